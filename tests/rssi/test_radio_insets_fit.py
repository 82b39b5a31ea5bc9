"""rf-fit's radio insets end to end: a box room whose x = 0 wall carries a metal panel that the scene does not tell
apart (the panel's surfels labelled as one more wall, so it shares the walls' material). The measurements come
from the room model itself with the panel metal and the rest concrete (first-order paths, no diffuse share): the
test is of the search, not of the physics (tests/rssi/test_room_physical.py and tests/model hold those). rf-fit
must find the panel as a radio inset over it and keep it on the held-out training links' verdict, which predicts
the test links better than the same fit without insets; without the panel it keeps none. Where the residuals gather
by chance (noise on the links reflecting off the panel's rectangle of a plain wall), the candidate found there is
dropped: no material or depth predicts noise."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from rfir_cli.main import app
from rfir_core.artifacts import read_artifact, write_artifact
from rfir_stages.geom import gaussians_from_mesh, write_scene_artifact
from rfir_stages.model.occlusion import FrozenGeometry
from rfir_stages.model.physical import MaterialValues
from rfir_stages.model.radio_insets import reflection_points
from rfir_stages.model.room import RoomGeometry, RoomSettings
from rfir_stages.simulate.scenes import _merge, rect_xy, wall

ROOM = (6.0, 5.0, 3.0)
PANEL = (1.5, 4.0, 0.8, 2.2)            # on the x = 0 wall: y0, y1, z0, z1 [m]
FREQ = 2.4e9
# first-order paths only, no diffuse share: as the measurements were made
SETS = ["--set", "rf_fit.room.max_order=1", "--set", "rf_fit.room.diffuse=false", "--set", "rf_fit.room.residual_terms=off",
        "--set", "rf_fit.room.reflection_ranges=false", "--set", "rf_fit.room.map_visibility=false",
        "--set", "rf_fit.physical.start_iterations=20"]


def _scene_fields():
    """(scene fields, label names): the walls, floor and ceiling, the x = 0 wall with the panel's rectangle as a part of
    its own ("wall_04": the walls' class)."""
    lx, ly, lz = ROOM
    y0, y1, z0, z1 = PANEL
    parts = [rect_xy(0, lx, 0, ly, 0.0, up=True), rect_xy(0, lx, 0, ly, lz, up=False),
             wall((0, 0, 0), (0, 1, 0), (1, 0, 0), ly, lz, [PANEL]), wall((lx, 0, 0), (0, 1, 0), (-1, 0, 0), ly, lz),
             wall((0, 0, 0), (1, 0, 0), (0, 1, 0), lx, lz), wall((0, ly, 0), (1, 0, 0), (0, -1, 0), lx, lz),
             wall((0, y0, z0), (0, 1, 0), (1, 0, 0), y1 - y0, z1 - z0)]
    names = ["floor", "ceiling", "wall_00", "wall_01", "wall_02", "wall_03", "wall_04"]
    v, f = _merge(parts)
    labels = np.concatenate([np.full(len(p[1]), i) for i, p in enumerate(parts)])
    return gaussians_from_mesh(v, f, 0.25, labels=labels), names


def _power_db(fields, tx, rx, panel: bool):
    """The room model's path gain [M] dB: concrete everywhere (half-space-like 20 cm), the panel metal when `panel`."""
    t = lambda k: torch.as_tensor(np.asarray(fields[f"gaussians/{k}"], np.float64))  # noqa: E731
    geom = FrozenGeometry(t("means"), t("log_scales"), t("rotations"), t("normals"))
    labels = np.asarray(fields["gaussians/labels"], np.int64)
    material = np.where((labels == 6) & panel, 1, 0)
    room = RoomGeometry(geom, torch.as_tensor(labels), material, RoomSettings(max_order=1, diffuse=False))
    n = int(material.max()) + 1
    mats = MaterialValues(torch.tensor([5.3, 1.0][:n]), torch.tensor([0.05, 1e7][:n]), 1.0, torch.zeros(n),
                          torch.tensor([0.2, 0.002][:n]))
    with torch.no_grad():
        p = room.links(tx, rx, np.full(len(tx), FREQ)).power(mats)[:, 0].numpy()
    return 10 * np.log10(p)


def _write(tmp_path, panel: bool, seed: int, noisy_spot: bool = False):
    fields, names = _scene_fields()
    write_scene_artifact(tmp_path / "scene.h5", fields, label_names=names)
    rng = np.random.default_rng(seed)
    n = 6000
    lo, hi = np.array([0.4, 0.4, 0.8]), np.array([ROOM[0] - 0.4, ROOM[1] - 0.4, 2.4])
    tx, rx = rng.uniform(lo, hi, (n, 3)), rng.uniform(lo, hi, (n, 3))
    split = (rng.random(n) < 0.2).astype(np.int64)
    gain_db = _power_db(fields, tx, rx, panel)
    if noisy_spot:        # links reflecting off the x = 0 wall inside the panel's rectangle: 4 dB of noise
        hit, valid, _ = reflection_points(tx, rx, np.array([1.0, 0.0, 0.0]), np.zeros(3))
        spot = valid & (hit[:, 1] > PANEL[0]) & (hit[:, 1] < PANEL[1]) & (hit[:, 2] > PANEL[2]) & (hit[:, 2] < PANEL[3])
        gain_db = gain_db + spot * rng.normal(0.0, 4.0, n)
    write_artifact(tmp_path / "meas.h5", "measurements",
                   {"tx_pos": tx, "rx_pos": rx, "freq_hz": np.array([FREQ]), "split": split,
                    "path_gain_db": gain_db[:, None],
                    "scene_bounds": np.array([[0.0, 0.0, 0.0], list(ROOM)])},
                   attrs={"task": "rssi", "scene": "panel_room"},
                   free={"simulator": {"@attrs": {"simulator": "tests: rfir's room model"}}})


@pytest.mark.parametrize("panel", [True, False])
def test_a_hidden_panel_is_found_and_kept_and_nothing_without_it(tmp_path, panel):
    _write(tmp_path, panel, seed=1)
    r = CliRunner().invoke(app, [*SETS, "rf-fit", str(tmp_path / "scene.h5"), str(tmp_path / "meas.h5"),
                                 "-o", str(tmp_path / "rf.h5")])
    assert r.exit_code == 0, r.output
    rf = read_artifact(tmp_path / "rf.h5", "rf")
    names = [str(s) for s in rf.attrs["label_names"]]
    if not panel:
        assert "radio_a_00" not in names, r.output
        scene = read_artifact(tmp_path / "scene.h5")
        # exact planes: no surface moved
        assert np.abs(np.asarray(rf["gaussians/means"]) - np.asarray(scene["gaussians/means"])).max() < 1e-9, r.output
        return
    assert "radio insets and surface depths: kept" in r.output, r.output
    info = CliRunner().invoke(app, ["info", str(tmp_path / "rf.h5")])
    assert info.exit_code == 0 and "radio_a: moved" in info.output, info.output
    lab = np.asarray(rf["gaussians/labels"])
    x = np.asarray(rf["gaussians/means"])[lab == names.index("radio_a_00")]
    assert np.all(x[:, 0] < 0.1)                                         # on the x = 0 wall
    y0, y1, z0, z1 = x[:, 1].min(), x[:, 1].max(), x[:, 2].min(), x[:, 2].max()
    # its surfels' centres (0.4 m apart) within a cell and a surfel of the panel's edges
    assert abs(y0 - PANEL[0]) < 0.8 and abs(y1 - PANEL[1]) < 0.8 and abs(z0 - PANEL[2]) < 0.8 and abs(z1 - PANEL[3]) < 0.8
    # held-out test links: the kept inset predicts them better than the fit without it
    out = tmp_path / "p.json"
    p = CliRunner().invoke(app, [*SETS, "predict", "rssi", str(tmp_path / "rf.h5"), "--measurements",
                                 str(tmp_path / "meas.h5"), "-o", str(tmp_path / "p.h5"), "--results", str(out)])
    assert p.exit_code == 0, p.output
    off = CliRunner().invoke(app, [*SETS, "--set", "rf_fit.room.radio_insets=off", "rf-fit", str(tmp_path / "scene.h5"),
                                   str(tmp_path / "meas.h5"), "-o", str(tmp_path / "rf_off.h5")])
    assert off.exit_code == 0, off.output
    q = CliRunner().invoke(app, [*SETS, "predict", "rssi", str(tmp_path / "rf_off.h5"), "--measurements",
                                 str(tmp_path / "meas.h5"), "-o", str(tmp_path / "q.h5"), "--results",
                                 str(tmp_path / "q.json")])
    assert q.exit_code == 0, q.output
    with_inset = json.loads(out.read_text())["metrics"]["mae_db"]
    without = json.loads((tmp_path / "q.json").read_text())["metrics"]["mae_db"]
    assert with_inset < without - 0.1, (with_inset, without)


def test_a_candidate_no_material_or_depth_explains_is_dropped(tmp_path):
    _write(tmp_path, panel=False, seed=2, noisy_spot=True)
    r = CliRunner().invoke(app, [*SETS, "rf-fit", str(tmp_path / "scene.h5"), str(tmp_path / "meas.h5"),
                                 "-o", str(tmp_path / "rf.h5")])
    assert r.exit_code == 0, r.output
    assert "radio insets: 1 candidate" in r.output and "radio_a dropped" in r.output, r.output
    rf = read_artifact(tmp_path / "rf.h5", "rf")
    assert "radio_a_00" not in [str(s) for s in rf.attrs["label_names"]], r.output
