"""Stated antenna patterns in the room model (docs/physics.md 8.10): each specular path's field is weighted by
sqrt(G_tx(departure)) sqrt(G_rx(arrival)) with the dipole's own field direction, each diffuse cell's power by
G_tx toward the cell and G_rx from it, and rf-fit takes the antennas a measurement file states.

The references are independent closed forms written here in numpy: a short dipole's gain 1.5 sin^2 of the angle
to its axis, a table interpolated in angle from the zenith, and for a perfectly conducting floor the image method
(the image of a dipole of axis (ax, ay, az) under the plane z = 0 has axis (-ax, -ay, az))."""
import json
import math

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from rfir_cli.main import app
from rfir_core.artifacts import read_artifact, write_artifact
from rfir_stages.geom import gaussians_from_mesh
from rfir_stages.model.antenna_patterns import AntennaPattern, EndAntenna, RoomAntennas
from rfir_stages.model.occlusion import FrozenGeometry
from rfir_stages.model.physical import MaterialValues
from rfir_stages.model.room import RoomGeometry, RoomPredictor, RoomSettings
from rfir_stages.model.room_diffuse import _cell_factors

from .helpers import C0, crosses_partition, links, write_scene

FREQ = 2.4e9
TILTED = (1 / math.sqrt(2), 0.0, 1 / math.sqrt(2))
TABLE_DEG = (0.0, 30.0, 60.0, 90.0, 120.0, 150.0, 180.0)
TABLE_GAIN = (0.2, 0.6, 1.4, 2.0, 1.4, 0.6, 0.2)


def unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def dipole_gain(d, axis):
    """1.5 sin^2 of the angle between unit directions d [N, 3] and axis [3]."""
    return 1.5 * (1.0 - (d @ np.asarray(axis)) ** 2)


def table_gain(d):
    """The test table's gain toward unit directions d [N, 3], its angle measured from the zenith (+z)."""
    return np.interp(np.degrees(np.arccos(np.clip(d[:, 2], -1, 1))), TABLE_DEG, TABLE_GAIN)


def floor_room(max_order=1, diffuse=False, antennas=None, size_m=30.0):
    """A RoomGeometry of one square floor (z = 0) of side size_m, one material."""
    h = size_m / 2
    v = np.array([[-h, -h, 0.0], [h, -h, 0], [h, h, 0], [-h, h, 0]])
    g = gaussians_from_mesh(v, np.array([[0, 1, 2], [0, 2, 3]]), 1.0, labels=np.zeros(2, np.int64))
    t = lambda key: torch.as_tensor(np.asarray(g[key], np.float64))  # noqa: E731
    geom = FrozenGeometry(t("gaussians/means"), t("gaussians/log_scales"), t("gaussians/rotations"),
                          t("gaussians/normals"))
    labels = np.asarray(g["gaussians/labels"], np.int64)
    settings = RoomSettings(max_order=max_order, diffuse=diffuse, patch_extent="disks")
    return RoomGeometry(geom, torch.as_tensor(labels), labels, settings, antennas=antennas)


def ends(n=7):
    """Transmitters at (0, 0, 1.5) and n receivers at 1 m height around it, at various azimuths and ranges."""
    ang = np.linspace(0.2, 2 * math.pi - 0.4, n)
    rng = np.linspace(1.5, 8.0, n)
    rx = np.stack([rng * np.cos(ang), rng * np.sin(ang), np.full(n, 1.0)], 1)
    return np.tile([[0.0, 0.0, 1.5]], (n, 1)), rx


def test_a_path_is_weighted_by_the_patterns_at_its_end_directions():
    """RoomPaths.gain is sqrt(G_tx(first leg) G_rx(last leg reversed)) of every path (direct, floor reflection),
    and a dipole's end field direction lies along its axis across the path (a tilted one's too)."""
    tx, rx = ends()
    antennas = RoomAntennas(EndAntenna(AntennaPattern("dipole"), TILTED),
                            EndAntenna(AntennaPattern("table", table_deg=TABLE_DEG, table_gain=TABLE_GAIN)))
    paths = floor_room(antennas=antennas).links(tx, rx, np.full(len(tx), FREQ)).paths
    link, order = paths.link.numpy(), paths.order.numpy()
    assert sorted(np.bincount(order)) == [len(tx), len(tx)]       # one direct and one floor reflection per link
    image = tx * [1, 1, -1]
    at_floor = image + (image[:, 2] / (image[:, 2] - rx[:, 2]))[:, None] * (rx - image)    # the reflection point
    depart = np.where((order == 0)[:, None], unit(rx - tx)[link], unit(at_floor - tx)[link])
    leave_rx = np.where((order == 0)[:, None], unit(tx - rx)[link], unit(at_floor - rx)[link])
    expected = np.sqrt(dipole_gain(depart, TILTED) * table_gain(leave_rx))
    np.testing.assert_allclose(paths.gain.numpy(), expected, rtol=1e-9)
    across = unit(np.asarray(TILTED) - depart * (depart @ np.asarray(TILTED))[:, None])
    np.testing.assert_allclose(np.abs((paths.e_tx.numpy() * across).sum(1)), 1.0, atol=1e-9)
    # isotropic ends: every path weighs 1
    iso = floor_room().links(tx, rx, np.full(len(tx), FREQ)).paths
    np.testing.assert_allclose(iso.gain.numpy(), 1.0)


def test_a_diffuse_cell_is_weighted_by_the_patterns_toward_it():
    room = floor_room(diffuse=True, size_m=8.0)
    tx, rx = ends(4)
    tx_end = EndAntenna(AntennaPattern("dipole"), TILTED)
    rx_end = EndAntenna(AntennaPattern("table", table_deg=TABLE_DEG, table_gain=TABLE_GAIN))
    iso, _, _ = _cell_factors(tx, rx, room.cells)
    weighted, _, _ = _cell_factors(tx, rx, room.cells, tx_end.gain, rx_end.gain)
    c = room.cells.centre[None]
    to_cell_t, to_cell_r = unit(c - tx[:, None]).reshape(-1, 3), unit(c - rx[:, None]).reshape(-1, 3)
    expected = iso * (dipole_gain(to_cell_t, TILTED) * table_gain(to_cell_r)).reshape(iso.shape)
    assert (iso > 0).sum() > 20
    np.testing.assert_allclose(weighted, expected, rtol=1e-9, atol=0)
    # and the room's links carry them: nothing obstructs the floor's cells, so each link's weights over the angle
    # nodes sum to its cells' weighted factors
    room.antennas = RoomAntennas(tx_end, rx_end)
    diffuse = room.links(tx, rx, np.full(len(tx), FREQ)).diffuse
    assert diffuse.obstructed.link.numel() == 0
    np.testing.assert_allclose(diffuse.weight.sum((1, 2)).numpy(), expected.sum(1), rtol=1e-9)


def dipole_field(source, axis_s, receiver, axis_r):
    """Received complex amplitude (P_T = 1 W) between short dipoles of axes axis_s at source [N, 3] and axis_r at
    receiver [N, 3]: lambda / (4 pi d) exp(-j k d) 1.5 (a_s across k) . (a_r across k)."""
    lam = C0 / FREQ
    d = np.linalg.norm(receiver - source, axis=1)
    k = (receiver - source) / d[:, None]
    across = lambda a: np.asarray(a)[None] - k * (k @ np.asarray(a))[:, None]  # noqa: E731
    return lam / (4 * math.pi * d) * np.exp(-2j * math.pi * d / lam) * 1.5 * (across(axis_s) * across(axis_r)).sum(1)


METAL = MaterialValues(torch.ones(1), torch.full((1,), 1e9), 0.0, torch.zeros(1), torch.full((1,), 0.05))


@pytest.mark.parametrize("axis_tx,axis_rx", [((0, 0, 1), (0, 0, 1)), (TILTED, (0, 0, 1)), (TILTED, (0, 1, 0))])
def test_dipoles_over_a_conducting_floor_match_the_image_method(axis_tx, axis_rx):
    """Dipoles over a perfectly conducting floor: the model's power is |direct + image|^2 within 0.1 dB, and its
    direct path alone is Friis times the two dipoles' gains (and polarisation match)."""
    tx, rx = ends()
    antennas = RoomAntennas(EndAntenna(AntennaPattern("dipole"), tuple(map(float, axis_tx))),
                            EndAntenna(AntennaPattern("dipole"), tuple(map(float, axis_rx))))
    links_ = floor_room(antennas=antennas).links(tx, rx, np.full(len(tx), FREQ))
    image_axis = np.asarray(axis_tx) * [-1, -1, 1]
    direct = dipole_field(tx, axis_tx, rx, axis_rx)
    total = direct + dipole_field(tx * [1, 1, -1], image_axis, rx, axis_rx)
    model_db = 10 * np.log10(links_.power(METAL)[:, 0].numpy())
    np.testing.assert_allclose(model_db, 20 * np.log10(np.abs(total)), atol=0.1)
    alone = links_.select_paths(links_.paths.order == 0)
    np.testing.assert_allclose(10 * np.log10(alone.power(METAL)[:, 0].numpy()), 20 * np.log10(np.abs(direct)),
                               atol=0.01)
    if axis_tx == axis_rx == (0, 0, 1):     # vertical dipoles: Friis x 1.5 sin^2(theta) at both ends
        d = np.linalg.norm(rx - tx, axis=1)
        sin2 = 1 - ((rx - tx)[:, 2] / d) ** 2
        friis = (C0 / FREQ / (4 * math.pi * d)) ** 2 * (1.5 * sin2) ** 2
        np.testing.assert_allclose(20 * np.log10(np.abs(direct)), 10 * np.log10(friis), atol=1e-9)


def reference_dipole_db(tx, rx, wall_loss_db=8.0, floor_gamma=-0.4):
    """The reduced room's closed form of helpers.reference_gain_db between vertical dipoles: each ray weighted by
    1.5 sin^2 of its angle to the vertical at both ends."""
    lam = C0 / FREQ
    k = 2 * math.pi / lam
    img = tx * np.array([1, 1, -1])
    total = 0
    for src, gamma in ((tx, 1.0), (img, floor_gamma)):
        d = np.linalg.norm(rx - src, axis=1)
        g = 1.5 * (1 - ((rx - src)[:, 2] / d) ** 2)
        total = total + gamma * g * lam / (4 * math.pi * d) * np.exp(-1j * k * d)
    block = crosses_partition(tx, rx) | crosses_partition(img, rx)
    return 20 * np.log10(np.abs(total * np.where(block, 10 ** (-wall_loss_db / 20), 1.0)))


FIT = ["--set", "rf_fit.physical.iterations=40", "--set", "rf_fit.physical.start_iterations=10",
       "--set", "rf_fit.room.reflection_ranges=false", "--set", "rf_fit.room.tabulated_materials=false",
       "--set", "rf_fit.room.residual_terms=off"]


def test_rf_fit_takes_a_stated_dipole_and_the_model_records_it(tmp_path):
    """A measurement file stating dipole:0,0,1 on both ends fits without refusal; the model records the antennas,
    `rfir info` names them, and the model's predictions carry the dipoles' gains."""
    write_scene(tmp_path / "scene.h5", spacing_m=0.3)
    tx, rx, tx_id, rx_id = links()
    t, r = tx[tx_id], rx[rx_id]
    split = np.zeros(len(t), np.int64)
    split[np.random.default_rng(0).permutation(len(t))[: len(t) // 5]] = 1
    data = {"tx_pos": t, "rx_pos": r, "freq_hz": np.array([FREQ]), "path_gain_db": reference_dipole_db(t, r)[:, None],
            "tx_id": tx_id, "rx_id": rx_id, "split": split}
    write_artifact(tmp_path / "meas.h5", "measurements", data,
                   attrs={"task": "rssi", "scene": "testroom", "antenna_tx": "dipole:0,0,1",
                          "antenna_rx": "dipole:0,0,1", "polarisation": "V"},
                   free={"simulator": {"@attrs": {"simulator": "tests reference model"}}})
    r_fit = CliRunner().invoke(app, [*FIT, "rf-fit", str(tmp_path / "scene.h5"), str(tmp_path / "meas.h5"),
                                     "-o", str(tmp_path / "rf.h5")])
    assert r_fit.exit_code == 0, r_fit.output
    assert "antennas tx dipole:0,0,1, rx dipole:0,0,1 (stated by the measurements)" in " ".join(r_fit.output.split())
    rf = read_artifact(tmp_path / "rf.h5", "rf")
    attrs = rf.free["model@attrs"]
    assert (attrs["antenna_tx"], attrs["antenna_rx"]) == ("dipole:0,0,1", "dipole:0,0,1")
    info = CliRunner().invoke(app, ["info", str(tmp_path / "rf.h5")], terminal_width=200)
    assert info.exit_code == 0 and "antennas: tx dipole:0,0,1, rx dipole:0,0,1" in info.output
    # the loaded model weights its paths with the dipoles: straight below a transmitter a receiver hears little
    model = RoomPredictor(rf)
    assert model.room.antennas.tx.pattern.kind == "dipole" == model.room.antennas.rx.pattern.kind
    below = model.path_gain_db(np.array([[1.0, 1.0, 2.0]]), np.array([[1.0, 1.0, 0.3]]))
    side = model.path_gain_db(np.array([[1.0, 1.0, 2.0]]), np.array([[1.0 + 1.7, 1.0, 2.0]]))
    assert below[0] < side[0] - 10     # isotropic ends: about equal (both 1.7 m, one free-space path each)


SMALL_GRID = ["--set", "simulate.rssi.tx_grid=[2,1]", "--set", "simulate.rssi.rx_grid=[4,3]"]


@pytest.mark.parametrize("pattern,stated", [("iso", "isotropic"), ("dipole", "dipole:0,0,1")])
def test_simulate_states_its_antenna_and_sionna_agrees_with_the_closed_form(tmp_path, pattern, stated):
    """rfir simulate's rssi antenna (Sionna RT's pattern) is stated in its measurements, and in the empty scene (the
    direct path alone) Sionna's path gain is Friis times that pattern's gains: 1.5 sin^2 at each end for its dipole."""
    pytest.importorskip("sionna.rt")
    r = CliRunner().invoke(app, [*SMALL_GRID, "--set", f'simulate.rssi.antenna="{pattern}"', "simulate", "empty",
                                 str(tmp_path / "sim"), "--task", "rssi", "--no-photos"])
    assert r.exit_code == 0, r.output
    meas = read_artifact(tmp_path / "sim" / "measurements.h5", "measurements")
    assert (meas.attrs["antenna_tx"], meas.attrs["antenna_rx"], meas.attrs["polarisation"]) == (stated, stated, "V")
    tx, rx = np.asarray(meas["tx_pos"]), np.asarray(meas["rx_pos"])
    d = np.linalg.norm(rx - tx, axis=1)
    gains = (1.5 * (1 - ((rx - tx)[:, 2] / d) ** 2)) ** 2 if pattern == "dipole" else 1.0
    friis_db = 10 * np.log10((C0 / np.asarray(meas["freq_hz"])[0] / (4 * math.pi * d)) ** 2 * gains)
    assert len(d) == 24
    np.testing.assert_allclose(np.asarray(meas["path_gain_db"])[:, 0], friis_db, atol=0.01)


@pytest.mark.slow
def test_the_classroom_with_sionna_dipoles_is_fitted_better_with_them_stated(tmp_path):
    """Sionna RT's classroom between vertical dipoles (stated by simulate): the room model with the dipoles stated
    predicts the held-out links better than the same fit assuming isotropic antennas (residual terms off: the
    physics alone), and its line-of-sight paths are Friis times the two dipole gains."""
    pytest.importorskip("sionna.rt")
    run = lambda *a: CliRunner().invoke(app, [str(x) for x in a])  # noqa: E731
    r = run("--set", 'simulate.rssi.antenna="dipole"', "--set", "simulate.rssi.tx_grid=[2,2]",
            "--set", "simulate.rssi.rx_grid=[8,6]", "simulate", "classroom", tmp_path / "sim", "--task", "rssi",
            "--no-photos")
    assert r.exit_code == 0, r.output
    meas_path = tmp_path / "sim" / "measurements.h5"
    r = run("mesh-gaussians", tmp_path / "sim/meshes/classroom_gt.ply", "-o", tmp_path / "scene.h5", "--spacing", "0.8")
    assert r.exit_code == 0, r.output
    mae = {}
    for name, extra in (("stated", []), ("isotropic", ["--set", 'rf_fit.antenna="isotropic"'])):
        r = run(*extra, "--set", 'rf_fit.room.residual_terms="off"', "rf-fit", tmp_path / "scene.h5", meas_path,
                "-o", tmp_path / f"rf_{name}.h5")
        assert r.exit_code == 0, r.output
        res = tmp_path / f"{name}.json"
        r = run("predict", "rssi", tmp_path / f"rf_{name}.h5", "--measurements", meas_path, "-o",
                tmp_path / f"p_{name}.h5", "--results", res)
        assert r.exit_code == 0, r.output
        mae[name] = json.loads(res.read_text())["metrics"]["mae_db"]
    assert mae["stated"] < 1.5 and mae["stated"] < mae["isotropic"] - 0.5, mae
    model = RoomPredictor(read_artifact(tmp_path / "rf_stated.h5", "rf"))
    meas = read_artifact(meas_path, "measurements")
    tx, rx = np.asarray(meas["tx_pos"]), np.asarray(meas["rx_pos"])
    traced = model.room.links(tx, rx, np.full(len(tx), model.freq_hz))
    direct = (traced.paths.order == 0) & (traced.paths.kind == 0).all(1)     # crossing no surface
    with torch.no_grad():
        field, _ = traced.select_paths(direct).components(model.mats)
    seen = np.zeros(len(tx), bool)
    seen[traced.paths.link[direct].numpy()] = True
    d = np.linalg.norm(rx - tx, axis=1)
    friis = (C0 / model.freq_hz / (4 * math.pi * d)) ** 2 * (1.5 * (1 - ((rx - tx)[:, 2] / d) ** 2)) ** 2
    assert seen.sum() > len(tx) // 2
    np.testing.assert_allclose(20 * np.log10(np.abs(field.numpy()[seen])), 10 * np.log10(friis[seen]), atol=0.01)


def test_each_side_is_taken_as_stated_and_a_broken_statement_is_one_line_naming_the_file():
    from types import SimpleNamespace

    from rfir_core.errors import ConfigError
    from rfir_stages.model.antenna_patterns import room_antennas

    meas = SimpleNamespace(attrs={"antenna_tx": "dipole:0,1,1"})
    ant = room_antennas({"antenna": "auto"}, meas, "m.h5")
    assert ant.tx.text() == f"dipole:0,{1 / math.sqrt(2):g},{1 / math.sqrt(2):g}" and ant.rx.isotropic
    assert "antenna_rx not stated: isotropic assumed" in ant.words()
    assert RoomAntennas.from_attrs(ant.attrs()) == ant                    # what a model records reads back
    forced = room_antennas({"antenna": "dipole"}, meas, "m.h5")           # rf_fit.antenna: both ends, vertical
    assert forced.tx.text() == forced.rx.text() == "dipole:0,0,1" and forced.source == "rf_fit.antenna"
    assert room_antennas({}, SimpleNamespace(attrs={}), "m.h5").isotropic
    for attrs in ({"antenna_rx": "table:ant.csv"}, {"antenna_tx": "dipole:0,0,x"}):
        with pytest.raises(ConfigError) as err:
            room_antennas({"antenna": "auto"}, SimpleNamespace(attrs=attrs), "m.h5")
        assert str(err.value).startswith("m.h5: ") and "\n" not in str(err.value)
