"""The `flat` scene (closed shell, rooms, labels) and the measured-like transform (no Sionna)."""
from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest

from rfir_core.artifacts import read_artifact, write_artifact
from rfir_core.config import load_defaults
from rfir_core.errors import ConfigError
from rfir_stages.geom.mesh_io import read_ply_mesh
from rfir_stages.simulate import measured_like as ml
from rfir_stages.simulate.rssi import grid_positions
from rfir_stages.simulate.scenes import build_scene
from rfir_stages.simulate.settings import parse_settings

SHELL = ("floor", "ceiling", "outer_wall", "window", "entrance_door")

SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"


def _ray_hits(origins, dirs, tri):
    """[N] bool: ray i meets one of the triangles tri [T, 3, 3] at t > 0 (Moller-Trumbore, both sides)."""
    e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    p = np.cross(dirs[:, None], e2[None])
    det = np.einsum("tk,ntk->nt", e1, p)
    ok = np.abs(det) > 1e-12
    inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
    s = origins[:, None] - tri[None, :, 0]
    u = np.einsum("ntk,ntk->nt", s, p) * inv
    q = np.cross(s, e1[None])
    v = np.einsum("nk,ntk->nt", dirs, q) * inv
    t = np.einsum("tk,ntk->nt", e2, q) * inv
    return np.any(ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (t > 1e-9), axis=1)


def test_flat_shell_is_closed_and_faces_inward():
    spec = build_scene("flat")
    np.testing.assert_allclose(spec.bounds, [[0, 0, 0], [9, 7, 2.7]])
    shell = [o for o in spec.objects if o.name.startswith(SHELL)]
    tri = np.concatenate([o.vertices[o.faces] for o in shell])
    rng = np.random.default_rng(0)
    origins = np.stack([rng.uniform(0.2, 8.8, 400), rng.uniform(0.2, 6.8, 400), rng.uniform(0.2, 2.5, 400)], 1)
    dirs = rng.normal(size=(400, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    assert _ray_hits(origins, dirs, tri).all()           # no ray leaves through a gap (windows, door closed)
    # without the window panes, rays do leave: the check can fail
    open_shell = np.concatenate([o.vertices[o.faces] for o in shell if not o.name.startswith("window")])
    assert not _ray_hits(origins, dirs, open_shell).all()
    centre = np.array([4.5, 3.5, 1.35])
    for o in shell:
        if o.name.startswith(("outer_wall", "floor", "ceiling")):
            v = o.vertices[o.faces]
            n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
            assert (np.einsum("ij,ij->i", n, centre - v.mean(1)) > 0).all(), o.name


def test_flat_rooms_materials_and_labels():
    spec = build_scene("flat")
    mats = {o.name: o.radio_material for o in spec.objects}
    assert mats["brick_wall"] == "brick" and mats["partition_west"] == mats["partition_east"] == "plasterboard"
    assert {mats[n] for n in mats if n.startswith("outer_wall")} == {"concrete"}
    assert sum(n.startswith("window") for n in mats) >= 3 and all(mats[n] == "glass" for n in mats if n.startswith("window"))
    assert mats["fridge"] == "metal" and mats["sofa"] == "chipboard" and mats["dining_table"] == "wood"
    assert set(spec.info["floorplan"]) <= set(mats) and "fridge" not in spec.info["floorplan"]
    assert len(set(spec.info["floorplan"].values())) == len(spec.info["floorplan"])
    # the flat's grids put a fixed antenna and many positions in every room
    s = parse_settings(None, scene="flat")
    anchors = grid_positions(spec.bounds, *s.tx_grid, s.tx_height_m, s.tx_margin_m)
    mobile = grid_positions(spec.bounds, *s.rx_grid, s.rx_height_m, s.rx_margin_m)
    assert len(spec.info["rooms"]) == 4
    def inside(p, box):
        x0, x1, y0, y1 = box
        return (p[:, 0] > x0) & (p[:, 0] < x1) & (p[:, 1] > y0) & (p[:, 1] < y1)

    for name, box in spec.info["rooms"].items():
        assert inside(anchors, box).sum() >= 1, name
        assert inside(mobile, box).sum() >= 100, name
    # the anchors stand clear of every object (they are not dropped by the transform)
    assert ml.clear_of_objects(spec, anchors, _settings().clearance_m).all()


def _settings(**kw) -> ml.MeasuredLikeSettings:
    table = dict(load_defaults()["simulate"]["measured_like"])
    table.update(kw)
    return ml.parse_settings(table)


def _simulated(n_side=(30, 24)):
    """Fake simulated rssi fields of the flat: 6 anchors (Sionna's Tx) x a grid (its Rx), Friis-like gains."""
    spec = build_scene("flat")
    s = parse_settings(None, scene="flat")
    tx = grid_positions(spec.bounds, *s.tx_grid, s.tx_height_m, s.tx_margin_m)
    rx = grid_positions(spec.bounds, *n_side, s.rx_height_m, s.rx_margin_m)
    tid, rid = np.repeat(np.arange(len(tx)), len(rx)), np.tile(np.arange(len(rx)), len(tx))
    d = np.linalg.norm(tx[tid] - rx[rid], axis=1)
    pg = -40.0 - 20 * np.log10(d)
    return spec, {"tx_pos": tx[tid], "rx_pos": rx[rid], "tx_id": tid, "rx_id": rid, "freq_hz": np.array([2.4e9]),
                  "path_gain_db": pg[:, None], "channel": (10 ** (pg / 20) * np.exp(0.7j))[:, None],
                  "scene_bounds": spec.bounds.astype(float)}


def test_pattern_is_normalised_over_the_sphere():
    c = np.linspace(-1, 1, 200001)              # cos(psi) is uniform on [-1, 1] over the sphere
    for q, f in ((1.0, 0.1), (3.0, 0.0), (0.0, 0.5)):
        mean = np.trapezoid(ml.pattern_gain(c, q, f), c) / 2
        assert mean == pytest.approx(1.0, abs=1e-6)
    g = ml.pattern_gain(np.array([1.0, -1.0]), 1.0, 0.1)
    assert 10 * math.log10(g[0] / g[1]) == pytest.approx(10.0)          # front-to-back 1 / f


def test_transform_is_seeded_and_its_terms_have_the_asked_statistics():
    spec, sim = _simulated()
    s = _settings(fading_std_db=2.0, tx_gain_std_db=3.0, rx_gain_std_db=4.0)
    a, truth, _ = ml.transform(sim, spec, s, seed=5)
    b, _, _ = ml.transform(sim, spec, s, seed=5)
    c, _, _ = ml.transform(sim, spec, s, seed=6)
    assert np.array_equal(a["path_gain_db"], b["path_gain_db"]) and not np.allclose(a["path_gain_db"], c["path_gain_db"])
    # ends swapped: the six anchors are now the receivers, the grid the transmitters
    assert len(np.unique(a["rx_id"])) == 6 and len(np.unique(a["tx_id"])) > 500
    assert np.allclose(a["rx_pos"][:, 2], 2.2) and np.allclose(a["tx_pos"][:, 2], 1.0)
    # positions near objects are gone (the fridge stands at x < 0.75, 4.3 < y < 5.0)
    fr = (a["tx_pos"][:, 0] < 0.95) & (a["tx_pos"][:, 1] > 4.1) & (a["tx_pos"][:, 1] < 5.2)
    assert not fr.any()
    # the effects add up exactly: measured = simulated + g_tx + g_rx + pattern + fading
    links = truth["links"]
    g_tx, g_rx = np.asarray(truth["tx"]["gain_db"]), np.asarray(truth["rx"]["gain_db"])
    np.testing.assert_allclose(a["path_gain_db"][:, 0], np.asarray(links["simulated_db"]) + g_tx[a["tx_id"]]
                               + g_rx[a["rx_id"]] + np.asarray(links["pattern_db"]) + np.asarray(links["fading_db"]),
                               atol=1e-9)
    np.testing.assert_allclose(np.abs(a["channel"][:, 0]) ** 2, 10 ** (a["path_gain_db"][:, 0] / 10), rtol=1e-9)
    np.testing.assert_allclose(np.angle(a["channel"]), 0.7, atol=1e-12)
    # statistics: fading N(0, 2) over ~4000 links, transmitter gains N(0, 3) over ~700 positions
    fading = np.asarray(links["fading_db"])
    assert abs(fading.mean()) < 0.1 and fading.std() == pytest.approx(2.0, rel=0.05)
    assert abs(g_tx.mean()) < 0.35 and g_tx.std() == pytest.approx(3.0, rel=0.1)
    # the data reveal a transmitter's gain: its links' mean residual (fading averaged over 6 receivers)
    resid = a["path_gain_db"][:, 0] - np.asarray(links["simulated_db"]) - np.asarray(links["pattern_db"]) \
        - g_rx[a["rx_id"]]
    est = np.bincount(a["tx_id"], resid) / np.bincount(a["tx_id"])
    assert np.corrcoef(est, g_tx)[0, 1] > 0.9
    # each device's boresight is a unit vector; patterns are not constant
    assert np.allclose(np.linalg.norm(truth["rx"]["boresight"], axis=1), 1.0)
    assert np.std(links["pattern_db"]) > 1.0


def test_run_writes_three_splits_a_floorplan_and_the_truth(tmp_path):
    spec, sim = _simulated((12, 10))
    write_artifact(tmp_path / "sim" / "measurements.h5", "measurements", sim, attrs={"task": "rssi", "scene": "flat"})
    lines = []
    written = ml.run(tmp_path / "sim", tmp_path / "out", dict(load_defaults()["simulate"]["measured_like"]), seed=1,
                     log=lines.append)
    assert any("fading" in line for line in lines) and any("floor plan" in line for line in lines)
    arts = {k: read_artifact(written[k], "measurements") for k in ("random", "room", "rx")}
    base = arts["random"]
    for art in arts.values():
        assert np.array_equal(art["path_gain_db"], base["path_gain_db"]) and "antenna_tx" not in art.attrs
    tx = base["tx_pos"]
    in_bedroom = (tx[:, 0] >= 5) & (tx[:, 0] < 9) & (tx[:, 1] < 3.8)
    assert np.array_equal(arts["room"]["split"] == 1, in_bedroom)
    assert len(np.unique(base["rx_id"][arts["rx"]["split"] == 1])) == 2
    assert abs((base["split"] == 1).mean() - 0.2) < 0.01
    plan = read_ply_mesh(written["floorplan"])
    names = set(plan.label_names.values())
    assert "thick_wall_00" in names and "window_00" in names and not any("fridge" in n or "sofa" in n for n in names)
    centres = plan.vertices[plan.faces].mean(1)
    fridge = (centres[:, 0] > 0.06) & (centres[:, 0] < 0.74) & (centres[:, 1] > 4.31) & (centres[:, 1] < 4.99) \
        & (centres[:, 2] > 0.01) & (centres[:, 2] < 1.79)
    assert not fridge.any()                                     # no furniture in the plan
    truth = json.loads((tmp_path / "out" / "truth.json").read_text())
    assert set(truth["splits"]) == {"random", "room", "rx"} and len(truth["rx"]["gain_db"]) == 6
    # the plan moves interior walls only, by a few centimetres
    assert set(truth["floorplan"]["offsets_m"]) == {"thick_wall_00", "thin_wall_00", "thin_wall_01"}
    assert max(abs(v) for v in truth["floorplan"]["offsets_m"].values()) < 0.15


def test_bad_settings_and_scenes_are_refused(tmp_path):
    table = dict(load_defaults()["simulate"]["measured_like"])
    with pytest.raises(ConfigError, match="unknown key"):
        ml.parse_settings({**table, "fadeing_std_db": 1.0})
    with pytest.raises(ConfigError, match="pattern_floor"):
        ml.parse_settings({**table, "pattern_floor": 2.0})
    with pytest.raises(ConfigError, match="holdout_room"):
        ml.protocols(build_scene("flat"), ml.parse_settings({**table, "holdout_room": "attic"}))
    with pytest.raises(ConfigError, match="floor plan"):
        ml.floorplan_mesh(build_scene("classroom"), np.random.default_rng(0), 0.03)
    # the command line lives in scripts/ (stages never parse arguments)
    spec = importlib.util.spec_from_file_location("measured_like_cli", SCRIPTS / "measured_like.py")
    cli = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(cli)
    assert cli.main([str(tmp_path / "nothing"), str(tmp_path / "out")]) == 2
    assert not (tmp_path / "out").exists()
