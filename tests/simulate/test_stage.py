"""End-to-end `rfir simulate` at reduced size: artifacts valid, conventions held, CLI wiring."""
from __future__ import annotations

import math

import numpy as np
import pytest
import typer
from typer.testing import CliRunner

pytest.importorskip("sionna.rt")

from rfir_core.artifacts import read_artifact  # noqa: E402
from rfir_cli.context import GlobalOptions  # noqa: E402
from rfir_stages.simulate import run  # noqa: E402
from rfir_stages.simulate.scene_edits import measurement_scene_edits  # noqa: E402
from rfir_stages.simulate.settings import _defaults  # noqa: E402


def _config(**sections) -> dict:
    c = _defaults()
    for key, value in sections.items():
        if isinstance(value, dict):
            c[key] = {**c[key], **value}
        else:
            c[key] = value
    return c


def test_rcs_quick_lego(tmp_path, check_quick_rcs_conventions):
    cfg = _config(photos=False, quick_sizes={"aspect_step_deg": 45.0, "ranges_m": [2.0, 4.0]})
    res = run("lego", tmp_path, cfg, quick=True)
    art = read_artifact(res.measurements["rcs"], "measurements")
    check_quick_rcs_conventions(art)
    sim = art.free["simulator@attrs"]
    assert sim["physics.diffuse"] and sim["antenna_tx"] == "horn" and sim["focused_sampling"]
    assert (tmp_path / "meshes" / "lego_gt.ply").exists()


def test_rssi_quick_classroom_with_effects(tmp_path):
    cfg = _config(photos=False, measurement={"noise_db": 0.5, "gain_offset_db": -3.0},
                  physics={"diffuse": False}, scene_edits=["whiteboard:delete", "door:material:glass"])
    res = run("classroom", tmp_path, cfg, quick=True)
    art = read_artifact(res.measurements["rssi"], "measurements")
    d = art.data
    assert art.attrs["task"] == "rssi"
    assert d["path_gain_db"].shape == (2 * 20, 1)
    assert d["tx_id"].max() == 1 and d["rx_id"].max() == 19
    assert set(np.unique(d["split"])) <= {0, 1} and d["split"].sum() == 8
    assert (d["path_gain_db"] < -30).all() and (d["path_gain_db"] > -90).all()
    sim = art.free["simulator@attrs"]
    assert sim["measurement.noise_db"] == 0.5 and sim["measurement.gain_offset_db"] == -3.0
    assert not sim["physics.diffuse"]
    assert measurement_scene_edits(art) == ["whiteboard:delete", "door:material:glass"]   # recorded, read back
    assert '"noise_db": 0.5' in art.provenance.to_attrs()["extra_json"]


def test_cli_simulate_h_target(tmp_path):
    from rfir_cli.commands import simulate as cmd

    app = typer.Typer()

    @app.callback()
    def _cb(ctx: typer.Context):
        ctx.obj = GlobalOptions(overrides=["simulate.quick_sizes.aspect_step_deg=90",
                                           "simulate.quick_sizes.wideband_num_freqs=16",
                                           "simulate.quick_sizes.num_views=3"])

    cmd.register(app)
    result = CliRunner().invoke(app, ["simulate", "h-target", str(tmp_path / "out"), "--quick"])
    assert result.exit_code == 0, result.output
    out = tmp_path / "out"
    rcs = read_artifact(out / "measurements.h5", "measurements")
    wb = read_artifact(out / "measurements_wideband.h5", "measurements")
    assert rcs.data["path_gain_db"].shape == (4, 2)
    assert wb.attrs["task"] == "wideband" and wb.data["path_gain_db"].shape == (4, 16)
    assert (out / "meshes" / "h-target_gt.ply").exists()
    if (out / "cameras.h5").exists():  # photos come from rfir_stages.render when present
        cams = read_artifact(out / "cameras.h5", "cameras")
        assert len(cams.data["image_names"]) == 3
    # the aspect 0 echo of the H's flat side (specular, image source): RCS ~ pi r^2
    assert rcs.data["rcs_dbsm"][0, 0] == pytest.approx(10 * math.log10(math.pi * 9.0), abs=1.0)


def test_unknown_scene_is_a_config_error(tmp_path):
    from rfir_core.errors import ConfigError

    with pytest.raises(ConfigError, match="unknown scene"):
        run("spaceship", tmp_path, _config(), quick=True)


def test_rssi_flat_drops_grid_points_inside_furniture(tmp_path):
    """Receivers of the grid inside the fridge or the bookshelf are not simulated into the file: the rows
    kept are Tx-major with consecutive ids, keep their random split, and the run says what it dropped."""
    cfg = _config(photos=False, rssi={"scenes": {"flat": {"tx_grid": [1, 1], "rx_grid": [5, 4]}}},
                  physics={"diffuse": False})
    res = run("flat", tmp_path, cfg, quick=False)
    d = read_artifact(res.measurements["rssi"], "measurements").data
    assert d["path_gain_db"].shape == (18, 1)                      # 20 grid points, 2 inside furniture
    assert d["rx_id"].tolist() == list(range(18)) and d["tx_id"].max() == 0
    rx = np.asarray(d["rx_pos"])
    assert not any(np.allclose(p, (0.3, 4.5667, 1.0), atol=1e-3) for p in rx)   # inside the fridge
    assert res.notes == ["dropped 2 of 20 receiver grid points within 0.05 m of an object's bounding box "
                         "(inside furniture or against it)"]
    assert (d["path_gain_db"] > -120).all()
