"""`rfir rf-fit` and `rfir predict rcs` end to end on a tiny scene, checkpoints, and bad input."""
import json

import numpy as np
import pytest
import torch
import typer
from typer.testing import CliRunner

from rfir_cli.artifacts import read_artifact, write_artifact
from rfir_cli.context import GlobalOptions
from rfir_cli.physics.closed_forms import rcs_from_path_gain
from rfir_stages.geom import write_scene_artifact
from rfir_stages.rf_fit.antennas import AntennaPattern
from rfir_stages.rf_fit.links import make_links, radar_links, scene_centre
from rfir_stages.rf_fit.render import Materials, RenderSettings, build_cache, render

from .helpers import DEG, box_fields, geometry

FAST = ["rf_fit.occlusion=brute-force", "rf_fit.grid_step_deg=10.0", "rf_fit.iterations=6",
        "rf_fit.checkpoint_every=3", "predict.occlusion=brute-force"]


def _app(overrides):
    from rfir_cli.commands import predict, rf_fit

    app = typer.Typer()

    @app.callback()
    def _cb(ctx: typer.Context):
        ctx.obj = GlobalOptions(overrides=list(overrides))

    rf_fit.register(app)
    predict.register(app)
    return app


def _measurements(path, fields, *, shift=0.0, split=None, ranges=(2.0,)):
    """RCS 'measurements' of the box made by the renderer (horn antennas), 20 deg steps."""
    geom = geometry(fields)
    aspects = np.arange(0, 360, 20) * DEG
    tx, rx, asp, rng = radar_links(aspects, np.asarray(ranges), scene_centre(geom).numpy())
    horn = AntennaPattern("horn")
    links = make_links(tx, rx, [2.4e9], scene_centre(geom), "rcs")
    g = geom.num
    m = Materials(torch.full((g,), 0.9, dtype=torch.float64), torch.full((g,), 3.0, dtype=torch.float64),
                  torch.full((g,), 0.5, dtype=torch.complex128))
    pg = 10 * np.log10(np.abs(render(build_cache(geom, links, horn, horn, None, RenderSettings(visibility=False)),
                                     m).numpy()) ** 2)
    rcs = 10 * np.log10(rcs_from_path_gain(10 ** (pg / 10), rng[:, None], 2.4e9, horn.boresight_gain,
                                           horn.boresight_gain))
    lo, hi = fields["gaussians/means"].min(0), fields["gaussians/means"].max(0)
    data = {"tx_pos": tx + shift, "rx_pos": rx + shift, "freq_hz": np.array([2.4e9]), "path_gain_db": pg,
            "rcs_dbsm": rcs, "aspect_rad": asp, "range_m": rng,
            "split": np.asarray(split if split is not None else np.arange(len(asp)) % 2, dtype=np.int64),
            "scene_bounds": np.stack([lo, hi]) + shift}
    write_artifact(path, "measurements", data, attrs={"task": "rcs", "scene": "box", "antenna_tx": "horn:40",
                                                      "antenna_rx": "horn:40"})
    return path


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    d = tmp_path_factory.mktemp("tiny")
    fields = box_fields(0.05, 0.05)
    write_scene_artifact(d / "scene.h5", fields)
    _measurements(d / "meas.h5", fields)
    return d, fields


def test_rf_fit_then_predict_rcs(tiny, tmp_path, monkeypatch):
    d, _ = tiny
    app = _app(FAST)
    r = CliRunner().invoke(app, ["rf-fit", str(d / "scene.h5"), str(d / "meas.h5"), "-o", str(tmp_path / "rf.h5")])
    assert r.exit_code == 0, r.output
    rf = read_artifact(tmp_path / "rf.h5", "rf")
    assert rf.data["rf/roughness"].min() >= 1.0 and 0 <= rf.data["rf/gamma_abs"].min() <= rf.data["rf/gamma_abs"].max() <= 1
    assert len(rf.free["training"]["loss_curve"]) == 6
    assert rf.free["model@attrs"]["antenna_kind"] == "horn"
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(app, ["predict", "rcs", str(tmp_path / "rf.h5"), "--measurements", str(d / "meas.h5"),
                                 "-o", str(tmp_path / "pred.h5"), "--plots", str(tmp_path / "plots")])
    assert r.exit_code == 0, r.output
    pred = read_artifact(tmp_path / "pred.h5", "predictions")
    assert pred.data["rcs_dbsm"].shape == (18, 1) and np.isfinite(pred.data["rcs_dbsm"]).all()
    res = json.loads((tmp_path / "results" / "pred.json").read_text())
    assert res["num_test"] == 9 and {"mae_db", "baseline_nearest_mae_db", "baseline_linear_mae_db"} <= set(res["metrics"])
    assert (tmp_path / "plots" / "rcs_2.4GHz_2m_polar.png").exists()
    assert (tmp_path / "plots" / "attributes.png").exists()
    # aspects x ranges without measurements
    r = CliRunner().invoke(app, ["predict", "rcs", str(tmp_path / "rf.h5"), "--aspects", "0:360:30",
                                 "--ranges", "2,3", "-o", str(tmp_path / "pred2.h5")])
    assert r.exit_code == 0, r.output
    assert read_artifact(tmp_path / "pred2.h5", "predictions").data["rcs_dbsm"].shape == (24, 1)


def test_checkpoint_and_resume(tiny, tmp_path):
    d, _ = tiny
    out = tmp_path / "rf.h5"
    r = CliRunner().invoke(_app(FAST), ["rf-fit", str(d / "scene.h5"), str(d / "meas.h5"), "-o", str(out)])
    assert r.exit_code == 0, r.output
    assert (tmp_path / "rf.h5.ckpt.pt").exists()
    r = CliRunner().invoke(_app(FAST + ["rf_fit.lr=0.2"]),
                           ["rf-fit", str(d / "scene.h5"), str(d / "meas.h5"), "-o", str(out), "--resume"])
    assert r.exit_code != 0 and "other inputs or settings" in r.output   # other settings: refused
    r = CliRunner().invoke(_app(FAST + ["rf_fit.iterations=9"]),
                           ["rf-fit", str(d / "scene.h5"), str(d / "meas.h5"), "-o", str(out), "--resume"])
    assert r.exit_code == 0, r.output
    rf = read_artifact(out, "rf")
    assert rf.free["training@attrs"]["resumed_at"] == 6 and len(rf.free["training"]["loss_curve"]) == 9


def test_bad_inputs_give_clear_errors(tiny, tmp_path):
    d, fields = tiny
    app = _app(FAST)
    fit = lambda meas: CliRunner().invoke(app, ["rf-fit", str(d / "scene.h5"), str(meas), "-o",  # noqa: E731
                                                str(tmp_path / "rf.h5")])
    r = fit(_measurements(tmp_path / "far.h5", fields, shift=100.0))
    assert r.exit_code == 2 and "another scene" in r.output
    r = fit(_measurements(tmp_path / "inside.h5", fields, ranges=(0.01,)))
    assert r.exit_code == 2 and "inside the geometry" in r.output
    r = fit(_measurements(tmp_path / "nosplit.h5", fields, split=np.ones(18)))
    assert r.exit_code == 5 and "empty training split" in r.output
    r = CliRunner().invoke(app, ["rf-fit", str(d / "scene.h5"), str(d / "meas.h5"), "-o", str(d / "meas.h5")])
    assert r.exit_code == 4 and "overwrite" in r.output


def test_predict_refuses_unfitted_frequencies_and_overwriting(tiny, tmp_path):
    d, _ = tiny
    app = _app(FAST)
    r = CliRunner().invoke(app, ["rf-fit", str(d / "scene.h5"), str(d / "meas.h5"), "-o", str(tmp_path / "rf.h5")])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(app, ["predict", "rcs", str(tmp_path / "rf.h5"), "--freqs", "5.8e9", "-o",
                                 str(tmp_path / "p.h5")])
    assert r.exit_code == 5 and "outside the fitted frequencies" in r.output
    r = CliRunner().invoke(app, ["predict", "rcs", str(tmp_path / "rf.h5"), "-o", str(tmp_path / "rf.h5")])
    assert r.exit_code == 4 and "never overwrites" in r.output


def _scattering_measurements(path, fields, coherent: bool, uniform: bool = False):
    """36 aspects of the box rendered by a coherent-only or an incoherent-only material set
    (uniform: one material for every Gaussian, else one drawn per Gaussian)."""
    geom = geometry(fields)
    aspects = np.arange(0, 360, 10) * DEG + 0.05
    tx, rx, asp, rng = radar_links(aspects, np.asarray([2.0]), scene_centre(geom).numpy())
    horn = AntennaPattern("horn")
    links = make_links(tx, rx, [2.4e9], scene_centre(geom), "rcs")
    g = geom.num
    gen = torch.Generator().manual_seed(4)
    a = torch.full((g,), 0.9, dtype=torch.float64)
    r = 1.0 + 4.0 * torch.rand(g, generator=gen, dtype=torch.float64)
    gamma = torch.polar(0.3 + 0.6 * torch.rand(g, generator=gen, dtype=torch.float64),
                        6.28 * torch.rand(g, generator=gen, dtype=torch.float64))
    if uniform:
        r, gamma = torch.full_like(r, 3.0), torch.full_like(gamma, 0.7 * np.exp(0.4j))
    m = Materials(a, r, gamma if coherent else torch.zeros(g, dtype=torch.complex128),
                  None if coherent else 0.2 + 0.6 * torch.rand(g, generator=gen, dtype=torch.float64),
                  None if coherent else r)
    from rfir_stages.rf_fit.render import render_power

    pg = 10 * np.log10(render_power(build_cache(geom, links, horn, horn, None, RenderSettings(visibility=False)),
                                    m).numpy())
    lo, hi = fields["gaussians/means"].min(0), fields["gaussians/means"].max(0)
    write_artifact(path, "measurements", {
        "tx_pos": tx, "rx_pos": rx, "freq_hz": np.array([2.4e9]), "path_gain_db": pg, "rcs_dbsm": pg + 40.0,
        "aspect_rad": asp, "range_m": rng, "split": np.zeros(len(asp), dtype=np.int64),
        "scene_bounds": np.stack([lo, hi])}, attrs={"task": "rcs", "scene": "box"})
    return path


@pytest.mark.parametrize("coherent", [True, False])
def test_scattering_auto_picks_the_model_that_made_the_data(tmp_path, coherent):
    from rfir_stages.rf_fit import run

    fields = box_fields(0.06, 0.03)
    scene = tmp_path / "scene.h5"
    write_scene_artifact(scene, fields)
    meas = _scattering_measurements(tmp_path / "m.h5", fields, coherent)
    res = run(scene, meas, tmp_path / "rf.h5", {"visibility": False, "iterations": 60, "checkpoint_every": 0,
                                                "scattering": "auto", "model": "free"})   # within the free family
    want = "coherent" if coherent else "incoherent"
    assert res.scattering["selected"] == want, res.scattering
    # 36 training links: every 10th row would hold out 4; 3 interleaved folds hold out all 36, still < 50: said
    assert res.scattering["validation_links"] == 36 and res.scattering["validation_folds"] == 3
    assert any("chosen on 36 validation links" in w for w in res.warnings)
    rf = read_artifact(tmp_path / "rf.h5", "rf")
    assert rf.free["training@attrs"]["scattering_selected"] == want
    if not coherent:
        assert np.all(np.asarray(rf["rf/gamma_abs"]) == 0.0)       # no coherent sum left to predict with


@pytest.mark.parametrize("uniform", [True, False])
def test_sharing_auto_picks_one_material_when_the_data_have_one(tmp_path, uniform):
    """sharing = auto: one material for the scene ("global") when one made the data, else per Gaussian."""
    from rfir_stages.rf_fit import run

    fields = box_fields(0.06, 0.03)
    scene = tmp_path / "scene.h5"
    write_scene_artifact(scene, fields)
    meas = _scattering_measurements(tmp_path / "m.h5", fields, True, uniform=uniform)
    res = run(scene, meas, tmp_path / "rf.h5", {"visibility": False, "iterations": 60, "checkpoint_every": 0,
                                                "scattering": "coherent", "sharing": "auto", "model": "free"})
    want = "global" if uniform else "gaussian"
    assert res.scattering["sharing_selected"] == want, res.scattering
    assert {"val_mae_coherent_gaussian_db", "val_mae_coherent_global_db"} <= set(res.scattering)
    rf = read_artifact(tmp_path / "rf.h5", "rf")
    assert rf.free["training@attrs"]["sharing"] == want
    gamma = np.asarray(rf["rf/gamma_abs"])
    assert (np.ptp(gamma) == 0.0) == uniform


def test_scattering_mode_is_checked(tmp_path):
    from rfir_cli.errors import ConfigError
    from rfir_stages.rf_fit import run

    fields = box_fields(0.06, 0.03)
    scene = tmp_path / "scene.h5"
    write_scene_artifact(scene, fields)
    meas = _scattering_measurements(tmp_path / "m.h5", fields, True)
    with pytest.raises(ConfigError, match="scattering"):
        run(scene, meas, tmp_path / "rf.h5", {"scattering": "magic"})
    with pytest.raises(ConfigError, match="diffuse = true"):
        run(scene, meas, tmp_path / "rf.h5", {"scattering": "incoherent", "diffuse": False})
    with pytest.raises(ConfigError, match="sharing"):
        run(scene, meas, tmp_path / "rf.h5", {"sharing": "per-brick"})
