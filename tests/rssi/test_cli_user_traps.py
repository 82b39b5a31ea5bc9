"""What a user meets fitting a tiny survey of their own and predicting from it: a model of the wrong kind
refused in one line, no 300-digit "standard error", a warning when the links cannot determine the
unknowns, an honest count of the optimiser's steps, material names shown whole."""
import re
import shutil

import h5py
import numpy as np
import pytest
from typer.testing import CliRunner

from rfir_cli.main import app

from .helpers import write_measurements, write_scene

ITERATIONS = 2
START_ITERATIONS = 3
FAST = ["--set", f"rf_fit.physical.iterations={ITERATIONS}", "--set",
        f"rf_fit.physical.start_iterations={START_ITERATIONS}"]


def _invoke(*args):
    return CliRunner().invoke(app, [*map(str, args)])


def _lines(result):
    return [line for line in result.output.splitlines() if line.strip()]


@pytest.fixture(scope="module")
def one_link(tmp_path_factory):
    """rf-fit of the reduced room's eight materials and both devices' gains on one measured link."""
    d = tmp_path_factory.mktemp("one_link")
    write_scene(d / "scene.h5")
    write_measurements(d / "one.h5", simulated=False, n_tx=(1, 1), n_rx=(1, 1))
    r = _invoke(*FAST, "--set", "rf_fit.room.device_gains=both", "rf-fit", d / "scene.h5", d / "one.h5",
                "-o", d / "rf.h5")
    assert r.exit_code == 0, r.output
    return d, r.output


def test_one_link_fit_says_the_links_cannot_determine_the_unknowns(one_link):
    _, out = one_link
    assert re.search(r"warning: .*1 training link for \d+ unknowns \(8 materials x eps_r, sigma, thickness", out), out
    assert not re.search(r"\d{12}", out), out                 # no 300-digit number of standard errors
    assert "1 training links" not in out and "1 training link x 1 freq" in out


def test_the_step_count_printed_is_the_steps_run(one_link):
    from rfir_stages.model.fit_physical import STARTS

    _, out = one_link
    steps = int(re.search(r"in (\d+) Adam steps", out).group(1))
    # every start runs START_ITERATIONS first, the fit ITERATIONS after them: more than --iterations, as printed
    assert steps >= len(STARTS) * START_ITERATIONS + ITERATIONS
    help_text = " ".join(_invoke("rf-fit", "--help").output.split())
    assert "rf_fit.physical.start_iterations steps before them" in help_text and "the total is printed" in help_text


def test_fit_materials_counts_every_step():
    import torch

    from rfir_stages.model.fit_physical import PhysicalFitConfig, STARTS, fit_materials

    class Agg:   # the fit's interface: power [M, K] of the materials (a stand-in that depends on them)
        def power(self, values, gain_db):
            return (values.eps_r.sum() * 1e-6 + torch.zeros(2, 1, dtype=torch.float64)) * 10 ** (gain_db / 10)

    cfg = PhysicalFitConfig(iterations=2, start_iterations=3, starts_kept=1)
    res = fit_materials(Agg(), 1, np.full((2, 1), -60.0), cfg)
    assert res.steps >= len(STARTS) * 3 + 2 and res.steps != cfg.iterations
    assert res.extra["num_data"] == 2 and res.extra["num_unknowns"] == 4


def test_info_shows_material_names_whole_on_a_narrow_terminal(one_link, tmp_path, monkeypatch):
    from rfir_cli import context

    d, _ = one_link
    rf = tmp_path / "named.h5"
    shutil.copy(d / "rf.h5", rf)
    with h5py.File(rf, "r+") as h5:
        names = [str(n) for n in h5["model"].attrs["material_names"]]
        long = ["wall_concrete_north_facade_" + n for n in names]
        h5["model"].attrs["material_names"] = np.asarray(long, dtype=h5py.string_dtype())
    monkeypatch.setattr(context.console, "_force_terminal", True)
    monkeypatch.setattr(context.console, "_width", 60)
    r = _invoke("info", rf)
    assert r.exit_code == 0, r.output
    for name in long:
        assert name in r.output, r.output


def test_predict_rcs_refuses_an_rssi_model(one_link, tmp_path):
    d, _ = one_link
    r = _invoke("predict", "rcs", d / "rf.h5", "-o", tmp_path / "p.h5")
    assert r.exit_code == 3 and len(_lines(r)) == 1, r.output
    assert "RSSI model" in r.output and "`rfir predict rssi`" in r.output and "inside the geometry" not in r.output


def test_predict_rssi_refuses_an_rcs_model(one_link, tmp_path):
    d, _ = one_link
    rf = tmp_path / "rcs_model.h5"
    shutil.copy(d / "rf.h5", rf)
    with h5py.File(rf, "r+") as h5:      # as rf-fit writes a model of RCS measurements: task rcs, no room model
        h5.attrs["task"] = "rcs"
        del h5["model"].attrs["model_kind"]
    r = _invoke("predict", "rssi", rf, "--tx", "1,1,1", "--grid", "1.0,0.5", "-o", tmp_path / "p.h5")
    assert r.exit_code == 3 and len(_lines(r)) == 1, r.output
    assert "RCS model" in r.output and "task 'rcs'" in r.output and "`rfir predict rcs`" in r.output
