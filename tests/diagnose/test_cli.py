"""`rfir diagnose` end to end: a ray tracer's prediction judged against measurements with a hidden gain,
an rf model whose named effect `rfir predict` then applies, and bad input."""
import json

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact, write_artifact
from rfir_cli.context import GlobalOptions



def _radar_measurements(path, fields):
    """RCS 'measurements' of the small metal box from the physical-optics solver (isotropic antennas,
    5 deg steps, 2 m)."""
    from rfir_core.physics.closed_forms import rcs_from_path_gain
    from rfir_stages.po import channel_from_amplitude, po_scattered_field
    from rfir_stages.model.links import radar_links
    from rfir_stages.simulate.scenes import box

    v, f = box((-0.05, -0.05, -0.05), (0.05, 0.05, 0.05))
    centre = 0.5 * (v.min(0) + v.max(0))
    tx, rx, asp, rng = radar_links(np.radians(np.arange(0, 360, 5.0)), np.array([2.0]), centre)
    mid = 0.5 * (tx + rx)
    s = po_scattered_field(v, f, np.array(["metal"] * len(f)), mid, mid, [2.4e9], near_field=True,
                           face_thickness=np.full(len(f), 0.003), ref_point=tuple(centre))
    r = np.linalg.norm(mid - centre, axis=1)
    pg = 20 * np.log10(np.abs(channel_from_amplitude(s, [2.4e9], r, r)))
    rcs = 10 * np.log10(rcs_from_path_gain(10 ** (pg / 10), rng[:, None], 2.4e9))
    lo, hi = fields["gaussians/means"].min(0), fields["gaussians/means"].max(0)
    write_artifact(path, "measurements", {"tx_pos": tx, "rx_pos": rx, "freq_hz": np.array([2.4e9]),
                                          "path_gain_db": pg, "rcs_dbsm": rcs, "aspect_rad": asp, "range_m": rng,
                                          "split": np.arange(len(asp)) % 2, "scene_bounds": np.stack([lo, hi])},
                   attrs={"task": "rcs", "scene": "box"})
    return path


def _app(overrides=()):
    from rfir_cli.commands import diagnose, predict, rf_fit

    app = typer.Typer()

    @app.callback()
    def _cb(ctx: typer.Context):
        ctx.obj = GlobalOptions(overrides=list(overrides))

    for m in (diagnose, rf_fit, predict):
        m.register(app)
    return app


def _invoke(args, overrides=()):
    return CliRunner().invoke(_app(overrides), [str(a) for a in args])


def _room(path, gain_db=0.0, seed=0):
    """RSSI-like measurements: 4 Tx x 60 Rx with free space plus +-3 dB structure."""
    tx = np.array([[1, 1, 2.2], [6, 1, 2.2], [1, 5, 2.2], [6, 5, 2.2]], float)
    rx = np.array([[x, y, 1.0] for x in np.linspace(0.5, 6.5, 10) for y in np.linspace(0.5, 5.5, 6)])
    t, r = np.repeat(tx, len(rx), 0), np.tile(rx, (len(tx), 1))
    d = np.linalg.norm(r - t, axis=1)
    pg = 20 * np.log10(0.125 / (4 * np.pi * d)) + 3 * np.sin(1.7 * r[:, 0]) * np.cos(1.3 * r[:, 1])
    pg = pg + gain_db + np.random.default_rng(seed).normal(0, 0.3, len(d))
    split = (np.random.default_rng(1).random(len(d)) < 0.25).astype(np.int64)
    write_artifact(path, "measurements", {"tx_pos": t, "rx_pos": r, "freq_hz": np.array([2.4e9]),
                                          "path_gain_db": pg[:, None], "split": split,
                                          "scene_bounds": np.array([[0, 0, 0], [7, 6, 3.0]])},
                   attrs={"task": "rssi", "scene": "synthetic"})
    return path


def test_a_ray_tracers_prediction_with_a_hidden_gain(tmp_path):
    model, meas = _room(tmp_path / "tracer.h5"), _room(tmp_path / "meas.h5", gain_db=-5.0, seed=3)
    r = _invoke(["diagnose", model, meas, "-o", tmp_path / "report"])
    assert r.exit_code == 0, r.output
    assert "gain_offset" in r.output
    res = json.loads((tmp_path / "report" / "results.json").read_text())
    assert res["named"][0]["effect"] == "gain_offset" and abs(res["named"][0]["params"]["offset_db"] + 5) < 0.2
    assert res["mae_after_db"] < 0.5 * res["mae_before_db"]
    for name in ("report.md", "residual_before.png", "residual_after.png", "effects.json"):
        assert (tmp_path / "report" / name).stat().st_size > 100
    md = (tmp_path / "report" / "report.md").read_text()
    assert "| 1 | **gain_offset** |" in md and "Where (before)" in md


def test_no_hidden_effect_names_none(tmp_path):
    model, meas = _room(tmp_path / "tracer.h5"), _room(tmp_path / "meas.h5", seed=4)
    r = _invoke(["diagnose", model, meas, "-o", tmp_path / "report"])
    assert r.exit_code == 0, r.output
    assert "no missing effect: no breakdown of the residual has structure" in r.output
    assert json.loads((tmp_path / "report" / "results.json").read_text())["named"] == []


def test_an_rf_model_gets_the_effect_and_predict_applies_it(tmp_path):
    from rfir_stages.geom import gaussians_from_mesh, write_scene_artifact
    from rfir_stages.simulate.scenes import box

    v, f = box((-0.05, -0.05, -0.05), (0.05, 0.05, 0.05))
    fields = gaussians_from_mesh(v, f, 0.05)
    write_scene_artifact(tmp_path / "scene.h5", fields)
    clean = _radar_measurements(tmp_path / "clean.h5", fields)
    fast = ["rf_fit.occlusion=brute-force", "rf_fit.physical.iterations=30", "rf_fit.physical.sharing=global",
            "rf_fit.physical.residual=off", "predict.occlusion=brute-force"]
    assert _invoke(["rf-fit", tmp_path / "scene.h5", clean, "-o", tmp_path / "rf.h5"], fast).exit_code == 0
    m = read_artifact(clean, "measurements")
    data = dict(m.data)
    data["path_gain_db"] = data["path_gain_db"] + 6.0
    data["rcs_dbsm"] = data["rcs_dbsm"] + 6.0
    write_artifact(tmp_path / "hot.h5", "measurements", data, attrs=dict(m.attrs))
    r = _invoke(["diagnose", tmp_path / "rf.h5", tmp_path / "hot.h5", "-o", tmp_path / "rep"], fast)
    assert r.exit_code == 0, r.output
    res = json.loads((tmp_path / "rep" / "results.json").read_text())
    assert res["named"][0]["effect"] == "gain_offset"
    fixed = tmp_path / "rep" / "model_with_effects.h5"
    for rf, name in ((fixed, "p1"), (tmp_path / "rf.h5", "p0")):
        r = _invoke(["predict", "rcs", rf, "--measurements", tmp_path / "hot.h5", "-o", tmp_path / f"{name}.h5",
                     "--results", tmp_path / f"{name}.json"], fast)
        assert r.exit_code == 0, r.output
    err = lambda p: np.mean(np.abs(np.asarray(read_artifact(p, "predictions")["path_gain_db"])  # noqa: E731
                                   - np.asarray(data["path_gain_db"])))
    assert err(tmp_path / "p1.h5") < err(tmp_path / "p0.h5") - 4.0


@pytest.mark.parametrize("case", ["missing", "not_a_model", "other_links"])
def test_bad_input_is_one_line(tmp_path, case):
    meas = _room(tmp_path / "meas.h5")
    model = {"missing": tmp_path / "nope.h5", "not_a_model": tmp_path / "junk.h5",
             "other_links": tmp_path / "other.h5"}[case]
    if case == "not_a_model":
        model.write_text("hello")
    if case == "other_links":
        m = read_artifact(meas, "measurements")
        data = dict(m.data)
        data["rx_pos"] = data["rx_pos"] + 0.5
        write_artifact(model, "measurements", data, attrs=dict(m.attrs))
    r = _invoke(["diagnose", model, meas, "-o", tmp_path / "rep"])
    assert r.exit_code in (2, 3, 5) and "Traceback" not in r.output
    assert str(model.name) in r.output
    assert not (tmp_path / "rep" / "results.json").exists()
