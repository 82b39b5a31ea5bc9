"""`rfir rf-fit` and `rfir predict rcs` end to end through the CLI on a small metal box (physical-optics data)."""
import json
import time

import h5py
import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact
from rfir_cli.context import GlobalOptions
from rfir_core.errors import InputFileError, SchemaError
from rfir_core.progress import NullProgress
from rfir_stages.geom import gaussians_from_mesh, write_scene_artifact
from rfir_stages.simulate.scenes import box

from .helpers import po_measurements

FAST = ["rf_fit.occlusion=brute-force", "rf_fit.antenna=isotropic", "rf_fit.physical.iterations=20",
        "rf_fit.physical.start_iterations=5", "rf_fit.physical.residual=off", "predict.occlusion=brute-force"]
BOX = box((-0.05, -0.05, -0.05), (0.05, 0.05, 0.05))


def _app(overrides):
    from rfir_cli.commands import predict, rf_fit

    app = typer.Typer()

    @app.callback()
    def _cb(ctx: typer.Context):
        ctx.obj = GlobalOptions(overrides=list(overrides))

    rf_fit.register(app)
    predict.register(app)
    return app


def _measurements(path, *, shift=0.0, split=None, ranges=(2.0,)):
    """PO 'measurements' of the metal box at 2.4 GHz, 20-degree aspects, odd aspects test."""
    v, f = BOX
    return po_measurements(path, v, f, np.array(["metal"] * len(f)), np.full(len(f), 0.003), [2.4e9],
                           np.arange(0, 360, 20.0), ranges=ranges, shift=shift, split=split)


class _Logged(NullProgress):
    def __init__(self):
        self.lines = []

    def log(self, message: str) -> None:
        self.lines.append(message)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    d = tmp_path_factory.mktemp("tiny")
    v, f = BOX
    write_scene_artifact(d / "scene.h5", gaussians_from_mesh(v, f, 0.03))
    _measurements(d / "meas.h5")
    return d


def test_rf_fit_then_predict_rcs(tiny, tmp_path, monkeypatch):
    d = tiny
    app = _app(FAST)
    r = CliRunner().invoke(app, ["rf-fit", str(d / "scene.h5"), str(d / "meas.h5"), "-o", str(tmp_path / "rf.h5")])
    assert r.exit_code == 0, r.output
    assert "materials per segment" in r.output or "one material for the scene" in r.output
    rf = read_artifact(tmp_path / "rf.h5", "rf")
    assert rf.free["model@attrs"]["family"] == "physical" and rf.free["model@attrs"]["antenna_kind"] == "isotropic"
    assert 0 <= rf.data["rf/gamma_abs"].min() <= rf.data["rf/gamma_abs"].max() <= 1
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(app, ["predict", "rcs", str(tmp_path / "rf.h5"), "--measurements", str(d / "meas.h5"),
                                 "-o", str(tmp_path / "pred.h5"), "--plots", str(tmp_path / "plots")])
    assert r.exit_code == 0, r.output
    pred = read_artifact(tmp_path / "pred.h5", "predictions")
    assert pred.data["rcs_dbsm"].shape == (18, 1) and np.isfinite(pred.data["rcs_dbsm"]).all()
    res = json.loads((tmp_path / "pred.json").read_text())
    assert res["num_test"] == 9 and {"mae_db", "baseline_nearest_mae_db", "baseline_linear_mae_db"} <= set(res["metrics"])
    assert (tmp_path / "plots" / "rcs_2.4GHz_2m_polar.png").exists()
    assert (tmp_path / "plots" / "attributes.png").exists()
    # aspects x ranges without measurements, at a frequency that was not fitted (the physical model predicts any)
    r = CliRunner().invoke(app, ["predict", "rcs", str(tmp_path / "rf.h5"), "--aspects", "0:360:30",
                                 "--ranges", "2,3", "--freqs", "5.8e9", "-o", str(tmp_path / "pred2.h5")])
    assert r.exit_code == 0, r.output
    assert read_artifact(tmp_path / "pred2.h5", "predictions").data["rcs_dbsm"].shape == (24, 1)


def test_bad_inputs_give_clear_errors(tiny, tmp_path):
    d = tiny
    app = _app(FAST)
    fit = lambda meas: CliRunner().invoke(app, ["rf-fit", str(d / "scene.h5"), str(meas), "-o",  # noqa: E731
                                                str(tmp_path / "rf.h5")])
    r = fit(_measurements(tmp_path / "far.h5", shift=100.0))
    assert r.exit_code == 2 and "another scene" in r.output
    r = fit(_measurements(tmp_path / "inside.h5", ranges=(0.01,)))
    assert r.exit_code == 2 and "inside the geometry" in r.output
    r = fit(_measurements(tmp_path / "nosplit.h5", split=np.ones(18)))
    assert r.exit_code == 5 and "empty training split" in r.output
    r = CliRunner().invoke(app, ["rf-fit", str(d / "scene.h5"), str(d / "meas.h5"), "-o", str(d / "meas.h5")])
    assert r.exit_code == 4 and "overwrite" in r.output
    assert not (tmp_path / "rf.h5").exists()


@pytest.mark.parametrize("key", ["rf_fit.model=free", "rf_fit.scattering=coherent", "rf_fit.sharing=gaussian",
                                 "rf_fit.wideband.net_iterations=10"])
def test_keys_of_the_retired_free_family_are_unknown(tiny, tmp_path, key):
    r = CliRunner().invoke(_app(FAST + [key]), ["rf-fit", str(tiny / "scene.h5"), str(tiny / "meas.h5"), "-o",
                                                str(tmp_path / "rf.h5")])
    name = key.split("=")[0]
    assert r.exit_code == 4 and f"unknown config key '{name}'" in r.output, r.output
    assert "Traceback" not in r.output and not (tmp_path / "rf.h5").exists()


def test_an_rf_artifact_of_the_free_family_is_refused_with_one_line(tiny, tmp_path):
    """What rf-fit wrote before the physical model was the only one: rf/* per Gaussian, no material/*."""
    from rfir_core.artifacts import validate_artifact, write_artifact

    scene = read_artifact(tiny / "scene.h5", "scene")
    g = len(scene["gaussians/means"])
    data = {k: v for k, v in scene.data.items() if k.startswith("gaussians/")}
    data.update({"rf/opacity": np.full(g, 0.9), "rf/roughness": np.full(g, 4.0), "rf/gamma_abs": np.full(g, 0.5),
                 "rf/gamma_phase_rad": np.zeros(g), "rf/freq_hz": np.array([2.4e9])})
    old = tmp_path / "old_rf.h5"
    with pytest.raises(SchemaError, match="retired per-Gaussian family"):   # the writer refuses it too
        write_artifact(old, "rf", data, attrs={"task": "rcs"})
    write_artifact(old, "scene", {k: v for k, v in data.items() if k.startswith("gaussians/")})
    with h5py.File(old, "r+") as h:           # an rf file as the free family wrote it
        h.attrs["kind"] = "rf"
        h.attrs["task"] = "rcs"
        for k, v in data.items():
            if k.startswith("rf/"):
                h[k] = v
    problems = validate_artifact(old)
    assert len(problems) == 1 and "retired per-Gaussian family" in problems[0] and "re-run rf-fit" in problems[0]
    r = CliRunner().invoke(_app(FAST), ["predict", "rcs", str(old), "--measurements", str(tiny / "meas.h5"),
                                        "-o", str(tmp_path / "p.h5")])
    assert r.exit_code == 3 and str(old) in r.output and "re-run rf-fit" in r.output, r.output
    assert "Traceback" not in r.output and not (tmp_path / "p.h5").exists()
    assert len([ln for ln in r.output.splitlines() if "re-run rf-fit" in ln]) == 1


def test_wall_time_covers_the_whole_command_with_its_parts(tiny, tmp_path):
    from rfir_stages.rf_fit import run

    began = time.time() - 5.0                # the command began 5 s before the stage (imports, parsing)
    cfg = {"antenna": "isotropic", "visibility": False,
           "physical": {"iterations": 10, "start_iterations": 5, "residual": "off", "sharing": "auto"}}
    res = run(tiny / "scene.h5", tiny / "meas.h5", tmp_path / "rf.h5", cfg, t_start=began)
    attrs = read_artifact(tmp_path / "rf.h5", "rf").free["training@attrs"]
    parts = attrs["trace_time_s"] + attrs["select_time_s"] + attrs["refit_time_s"]
    assert attrs["wall_time_s"] >= 5.0 + parts - 1e-6 and res.wall_time_s >= attrs["wall_time_s"]
    assert attrs["refit_time_s"] > 0
    assert set(res.timings_s) >= {"trace", "select", "fit", "total"}


def test_resume_reuses_the_model_selection_of_the_interrupted_run(tmp_path):
    """Two labels: the sharing is chosen by validation, recorded beside the output, and reused by --resume."""
    from rfir_stages.rf_fit import run

    v, f = BOX
    labels = (v[f].mean(1)[:, 0] > 0).astype(np.int64)
    write_scene_artifact(tmp_path / "scene.h5", gaussians_from_mesh(v, f, 0.03, labels=labels))
    meas = _measurements(tmp_path / "m.h5", split=np.zeros(18))
    cfg = {"antenna": "isotropic", "visibility": False,
           "physical": {"iterations": 10, "start_iterations": 5, "residual": "off"}}
    first = run(tmp_path / "scene.h5", meas, tmp_path / "rf.h5", cfg)
    assert (tmp_path / "rf.h5.ckpt.pt.selection").exists() and "val_mae_class_db" in first.selection
    log = _Logged()
    again = run(tmp_path / "scene.h5", meas, tmp_path / "rf.h5", cfg, resume=True, progress=log)
    assert any("model selection reused" in line for line in log.lines), log.lines
    assert not any("validation MAE on" in line for line in log.lines)          # no candidate was fitted again
    assert again.selection == first.selection
    other = _Logged()                           # other settings: selected afresh
    run(tmp_path / "scene.h5", meas, tmp_path / "rf.h5", dict(cfg, loss="db_huber"), resume=True, progress=other)
    assert any("validation MAE on" in line for line in other.lines)
    (tmp_path / "rf.h5.ckpt.pt.selection").write_bytes(b"not a record")
    with pytest.raises(InputFileError, match="cannot read the saved model selection"):
        run(tmp_path / "scene.h5", meas, tmp_path / "rf.h5", dict(cfg, loss="db_huber"), resume=True)
