"""Antenna axes per link in the room model (docs/physics.md 8.10): a measurements file's tx_axis / rx_axis [L, 3] (a
dipole's axis, a horn's or table's boresight) replace the antenna attribute's one axis for each link, in the fit and in
the prediction; `rfir import csv` reads them from axis or heading columns.

The references are closed forms written here in numpy: a short dipole's gain 1.5 sin^2 of the angle to its axis, the
cos^q horn G0 cos^q(theta) over its front hemisphere (q from the half-power beamwidth, G0 = 2 (q + 1)), and Friis'
free-space amplitude lambda / (4 pi d) for the direct path."""
import json
import math

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from rfir_cli.main import app
from rfir_core.artifacts import read_artifact
from rfir_stages.model.antenna_patterns import AntennaPattern, EndAntenna, LinkAxes, RoomAntennas, end_antenna
from rfir_stages.model.room import RoomPredictor
from rfir_stages.model.room_diffuse import _cell_factors

from .helpers import C0, links, reference_gain_db, write_scene
from .test_room_antennas import FIT, METAL, floor_room, unit

FREQ = 2.4e9
HPBW = 60.0
TILTED = (1 / math.sqrt(2), 0.0, 1 / math.sqrt(2))
SIDEWAYS = (0.0, 1.0, 0.0)
UPWARD = (0.0, 0.0, 1.0)        # a receiving horn's boresight: every ring's transmitter is above its receivers


def dipole_gain(d, axes):
    """1.5 sin^2 of the angle between unit directions d [N, 3] and unit axes [N, 3]."""
    return 1.5 * (1.0 - (d * axes).sum(1) ** 2)


def horn_gain(d, axes, hpbw_deg=HPBW):
    """The cos^q horn toward unit directions d [N, 3] about boresights axes [N, 3]: G0 cos^q over the front
    hemisphere, cos^q(hpbw / 2) = 1/2, G0 = 2 (q + 1) (its power integrates to 4 pi), 0 behind."""
    q = math.log(0.5) / math.log(math.cos(math.radians(hpbw_deg) / 2))
    c = (d * axes).sum(1)
    return np.where(c > 0, 2 * (q + 1) * np.clip(c, 0, 1) ** q, 0.0)


def ring(n=9):
    """A transmitter at (0, 0, 1.5) and n receivers at 1 m height around it, at various azimuths and ranges."""
    ang = np.linspace(0.3, 2 * math.pi - 0.3, n)
    rng = np.linspace(1.5, 3.5, n)
    rx = np.stack([rng * np.cos(ang), rng * np.sin(ang), np.full(n, 1.0)], 1)
    return np.tile([[0.0, 0.0, 1.5]], (n, 1)), rx


def turned_axes(tx, rx, seed=3):
    """Per link: a dipole axis drawn at random (tx) and a horn boresight from the receiver roughly toward the
    transmitter, turned by a random offset (some links' transmitter lies behind their horn)."""
    g = np.random.default_rng(seed)
    return unit(g.normal(size=tx.shape)), unit(unit(tx - rx) + g.normal(scale=0.8, size=rx.shape))


def dipole_and_horn(tx_axis=(0.0, 0.0, 1.0), rx_axis=(0.0, 0.0, 1.0)):
    return RoomAntennas(EndAntenna(AntennaPattern("dipole"), tuple(tx_axis)),
                        EndAntenna(AntennaPattern("horn", hpbw_deg=HPBW), tuple(rx_axis)))


def test_each_path_is_weighted_by_its_own_links_dipole_and_horn():
    """Specular paths (direct, floor reflection): sqrt(G_dipole(departure about the link's tx axis) x
    G_horn(arrival, reversed, about the link's rx boresight)), the dipole's field along its link's axis across the
    path; diffuse cells: G_tx toward the cell times G_rx toward it, each about its link's axes."""
    tx, rx = ring()
    tx_axes, rx_axes = turned_axes(tx, rx)
    axes = LinkAxes(tx_axes, rx_axes)
    paths = floor_room(antennas=dipole_and_horn()).links(tx, rx, np.full(len(tx), FREQ), axes=axes).paths
    link, order = paths.link.numpy(), paths.order.numpy()
    assert sorted(np.bincount(order)) == [len(tx), len(tx)]       # one direct path and one floor reflection a link
    image = tx * [1, 1, -1]
    at_floor = image + (image[:, 2] / (image[:, 2] - rx[:, 2]))[:, None] * (rx - image)
    depart = np.where((order == 0)[:, None], unit(rx - tx)[link], unit(at_floor - tx)[link])
    toward_source = np.where((order == 0)[:, None], unit(tx - rx)[link], unit(at_floor - rx)[link])
    expected = np.sqrt(dipole_gain(depart, tx_axes[link]) * horn_gain(toward_source, rx_axes[link]))
    assert (expected == 0).any() and (expected > 0.5).any()      # some sources behind their horn, some in front
    np.testing.assert_allclose(paths.gain.numpy(), expected, rtol=1e-9, atol=1e-12)
    a = tx_axes[link]
    across = unit(a - depart * (depart * a).sum(1, keepdims=True))
    np.testing.assert_allclose(np.abs((paths.e_tx.numpy() * across).sum(1)), 1.0, atol=1e-9)

    room = floor_room(diffuse=True, size_m=8.0)
    iso = room.links(tx, rx, np.full(len(tx), FREQ)).diffuse.weight.sum((1, 2)).numpy()
    room.antennas = dipole_and_horn()
    weighted = room.links(tx, rx, np.full(len(tx), FREQ), axes=axes).diffuse.weight.sum((1, 2)).numpy()
    c = room.cells.centre[None]
    lambertian, _, _ = _cell_factors(tx, rx, room.cells)                    # [M, C], isotropic ends
    n_cells = c.shape[1]
    to_cell_t, to_cell_r = unit(c - tx[:, None]).reshape(-1, 3), unit(c - rx[:, None]).reshape(-1, 3)
    per_cell = dipole_gain(to_cell_t, np.repeat(tx_axes, n_cells, 0)) * horn_gain(to_cell_r, np.repeat(rx_axes, n_cells, 0))
    np.testing.assert_allclose(lambertian.sum(1), iso, rtol=1e-9)          # the weights' sum is the factors' sum
    np.testing.assert_allclose(weighted, (lambertian * per_cell.reshape(lambertian.shape)).sum(1), rtol=1e-9)


def test_an_axis_per_link_equal_to_the_stated_one_predicts_exactly_the_same():
    """Every link given the attribute's own axis predicts what the attribute alone predicts (paths and diffuse
    power), and other axes change the prediction: the per-link axes are what weights the links."""
    tx, rx = ring()
    room = floor_room(diffuse=True, size_m=8.0, antennas=dipole_and_horn(TILTED, UPWARD))
    f = np.full(len(tx), FREQ)
    alone = room.links(tx, rx, f).power(METAL)[:, 0].numpy()
    assert (alone > 0).all()
    same = room.links(tx, rx, f, axes=LinkAxes(np.tile(TILTED, (len(tx), 1)), np.tile(UPWARD, (len(tx), 1))))
    np.testing.assert_allclose(same.power(METAL)[:, 0].numpy(), alone, rtol=1e-12, atol=0)
    turned = room.links(tx, rx, f, axes=LinkAxes(*turned_axes(tx, rx))).power(METAL)[:, 0].numpy()
    assert np.abs(10 * np.log10(np.maximum(turned, 1e-30) / alone)).max() > 3.0


def test_a_stated_boresight_points_a_horn_and_reads_back():
    """horn:HPBW@AX,AY,AZ states a horn's boresight (normalised): the room takes it as the horn's axis, writes it
    back in the same spelling, and without one a horn points along +z."""
    end = end_antenna({"antenna_rx": "horn:60@0,2,0"}, "antenna_rx", "m.h5")
    assert end.axis == SIDEWAYS and end.text() == "horn:60@0,1,0"
    assert end_antenna({"antenna_rx": end.text()}, "antenna_rx", "m.h5") == end
    assert end_antenna({"antenna_rx": "horn:60"}, "antenna_rx", "m.h5").axis == (0.0, 0.0, 1.0)


def run(*args):
    return CliRunner().invoke(app, [str(a) for a in args], terminal_width=240)


def one_line_error(result, *words):
    """A refusal: non-zero exit, no traceback, one line of error naming `words` (the file and the column)."""
    assert result.exit_code != 0, result.output
    assert "Traceback" not in result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    lines = [ln for ln in result.output.splitlines() if "error" in ln.lower()]
    text = " ".join(result.output.split())
    assert len(lines) == 1, result.output
    for w in words:
        assert w in text, (w, result.output)


CSV_HEAD = "tx_x,tx_y,tx_z,rx_x,rx_y,rx_z,freq_hz,power_db"


def csv_rows(n=4):
    """n links from (0, 0, 1.5) to receivers 2..5 m away at 1 m, each a little below free space at 2.4 GHz."""
    out = []
    for i in range(n):
        x = 2.0 + i
        d = math.hypot(x, 0.5)
        out.append(f"0,0,1.5,{x:g},0,1,{FREQ:g},{20 * math.log10(C0 / FREQ / (4 * math.pi * d)) - 3:.3f}")
    return out


def test_csv_import_reads_headings_and_axes_and_refuses_bad_ones_on_one_line(tmp_path):
    """rx_heading_deg h -> rx_axis (cos h, sin h, 0); tx_ax, tx_ay, tx_az -> tx_axis normalised; the import says
    the convention. A zero vector, a NaN, an axis of two columns and a side given both ways are each refused on one
    line naming the file and the column."""
    rows = csv_rows()
    headings = [0.0, 90.0, 225.0, -30.0]
    tx_axes = [(0, 0, 2), (1, 0, 1), (0, 3, 0), (1, 1, 1)]
    body = [f"{r},{a[0]},{a[1]},{a[2]},{h}" for r, a, h in zip(rows, tx_axes, headings)]
    path = tmp_path / "links.csv"
    path.write_text("\n".join([CSV_HEAD + ",tx_ax,tx_ay,tx_az,rx_heading_deg", *body]) + "\n")
    r = run("import", "csv", path, "-o", tmp_path / "m.h5", "--antenna-tx", "dipole", "--antenna-rx", "horn:60")
    assert r.exit_code == 0, r.output
    text = " ".join(r.output.split())
    assert "antenna axis per link" in text and "(cos h, sin h, 0)" in text and "normalised" in text
    meas = read_artifact(tmp_path / "m.h5", "measurements")
    h = np.radians(headings)
    np.testing.assert_allclose(np.asarray(meas["rx_axis"]), np.stack([np.cos(h), np.sin(h), 0 * h], 1), atol=1e-12)
    np.testing.assert_allclose(np.asarray(meas["tx_axis"]), unit(np.asarray(tx_axes, float)), atol=1e-12)

    bad = {"zero": (CSV_HEAD + ",rx_ax,rx_ay,rx_az", [f"{rows[0]},0,0,0"], "rx_ax,rx_ay,rx_az"),
           "nan": (CSV_HEAD + ",rx_heading_deg", [f"{rows[0]},nan"], "rx_heading_deg"),
           "two columns": (CSV_HEAD + ",tx_ax,tx_ay", [f"{rows[0]},1,0"], "tx_az"),
           "both": (CSV_HEAD + ",rx_ax,rx_ay,rx_az,rx_heading_deg", [f"{rows[0]},1,0,0,10"], "rx_heading_deg")}
    for name, (head, lines, column) in bad.items():
        p = tmp_path / f"bad_{name.replace(' ', '_')}.csv"
        p.write_text("\n".join([head, *lines]) + "\n")
        out = tmp_path / f"bad_{name.replace(' ', '_')}.h5"
        one_line_error(run("import", "csv", p, "-o", out), p.name, column)
        assert not out.exists()
    for flag in ("horn:60@0,0,0", "dipole@1,0,0", "horn:60@1,0"):      # a stated boresight: three numbers, horn or table
        one_line_error(run("import", "csv", path, "-o", tmp_path / "bad_flag.h5", "--antenna-rx", flag), flag)
        assert not (tmp_path / "bad_flag.h5").exists()


def test_rf_fit_and_predict_take_each_links_horn_boresight(tmp_path):
    """Receivers with horns whose boresight is each link's (rx_axis): rf-fit says the rx side is oriented per link,
    the model records it (rfir info), and predict rssi with the measurements predicts about those boresights: its
    path gains are the model's with the axes, not without; a map (links without axes) is predicted about the stated
    boresight, with a warning."""
    write_scene(tmp_path / "scene.h5", spacing_m=0.3)
    tx, rx, tx_id, rx_id = links()
    t, r = tx[tx_id], rx[rx_id]
    rx_axis = unit(unit(t - r) * [1, 1, 0] + np.random.default_rng(0).normal(scale=0.3, size=r.shape) * [1, 1, 0])
    gain_db = reference_gain_db(t, r, FREQ) + 10 * np.log10(np.maximum(horn_gain(unit(t - r), rx_axis), 1e-3))
    lines = [",".join(f"{v:.6g}" for v in (*a, *b, FREQ, g, *x)) + f",{s}"
             for a, b, g, x, s in zip(t, r, gain_db, rx_axis, np.arange(len(t)) % 5 == 0)]
    csv_path = tmp_path / "links.csv"
    csv_path.write_text("\n".join([CSV_HEAD + ",rx_ax,rx_ay,rx_az,split",
                                   *[ln.replace(",True", ",test").replace(",False", ",train") for ln in lines]]) + "\n")
    assert run("import", "csv", csv_path, "-o", tmp_path / "m.h5", "--antenna-rx", "horn:60").exit_code == 0
    fit = run(*FIT, "rf-fit", tmp_path / "scene.h5", tmp_path / "m.h5", "-o", tmp_path / "rf.h5")
    assert fit.exit_code == 0, fit.output
    assert "rx horn:60 (axis per link)" in " ".join(fit.output.split())
    info = run("info", tmp_path / "rf.h5")
    assert info.exit_code == 0 and "rx axis per link (rx_axis)" in " ".join(info.output.split()), info.output
    res = tmp_path / "res.json"
    pred = run("predict", "rssi", tmp_path / "rf.h5", "--measurements", tmp_path / "m.h5", "-o", tmp_path / "p.h5",
               "--results", res)
    assert pred.exit_code == 0, pred.output
    predicted = np.asarray(read_artifact(tmp_path / "p.h5", "predictions")["path_gain_db"])[:, 0]
    model = RoomPredictor(read_artifact(tmp_path / "rf.h5", "rf"))
    assert model.room.antennas.per_link == ("rx",)
    meas = read_artifact(tmp_path / "m.h5", "measurements")                 # positions and axes as the CSV wrote them
    t, r, stored = (np.asarray(meas[k]) for k in ("tx_pos", "rx_pos", "rx_axis"))
    np.testing.assert_allclose(stored, rx_axis, atol=1e-5)
    with torch.no_grad():
        oriented = model.path_gain_db(t, r, axes=LinkAxes(rx=stored))
        upward = model.path_gain_db(t, r)
    np.testing.assert_allclose(predicted, oriented, atol=1e-6)
    assert np.abs(predicted - upward).max() > 10.0
    assert json.loads(res.read_text())["metrics"]["mae_db"] < 3.0
    grid = run("predict", "rssi", tmp_path / "rf.h5", "--tx", "1,1,2", "--grid", "1,1.0", "-o", tmp_path / "map.h5")
    assert grid.exit_code == 0, grid.output
    assert "oriented per link" in " ".join(grid.output.split())


def rotation(yaw, pitch, roll):
    """Sionna RT's orientation (yaw, pitch, roll) [rad] as a matrix: Rz(yaw) Ry(pitch) Rx(roll)."""
    cz, sz, cy, sy, cx, sx = (f(a) for a in (yaw, pitch, roll) for f in (math.cos, math.sin))
    rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    return rz @ ry @ rx


@pytest.mark.slow
def test_sionna_rotated_dipoles_agree_with_the_links_axes():
    """Sionna RT's empty scene, a transmitter and receivers each turned by its own orientation, its "dipole" pattern
    (a short dipole along the device's z axis): the line-of-sight path gain equals the room model's direct path with
    each link's dipole axes (the devices' rotated z axes) within 0.01 dB, and the same links about vertical axes do
    not."""
    pytest.importorskip("sionna.rt")
    from rfir_stages.simulate.radio_scene import set_variant

    set_variant()
    import sionna.rt as rt

    scene = rt.load_scene()
    scene.frequency = FREQ
    scene.tx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="dipole", polarization="V")
    scene.rx_array = rt.PlanarArray(num_rows=1, num_cols=1, pattern="dipole", polarization="V")
    tx_turn = (0.3, 0.5, 0.2)
    rx_turns = np.array([[0.0, 0.0, 0.0], [0.5, 0.7, 0.0], [1.0, -0.4, 0.3], [-0.8, 0.2, 1.1], [2.0, 1.2, -0.5]])
    rx = np.array([[3.0, 0.5, 1.0], [-2.0, 2.5, 1.2], [1.0, -3.0, 0.8], [2.0, 2.0, 2.5], [-1.5, -1.0, 0.5]])
    tx = np.tile([[0.0, 0.0, 1.5]], (len(rx), 1))
    scene.add(rt.Transmitter(name="tx", position=tx[0].tolist(), orientation=list(tx_turn)))
    for i, (p, turn) in enumerate(zip(rx, rx_turns)):
        scene.add(rt.Receiver(name=f"rx{i}", position=p.tolist(), orientation=turn.tolist()))
    paths = rt.PathSolver()(scene, max_depth=0, los=True, specular_reflection=False, diffuse_reflection=False,
                            refraction=False)
    re, im = (np.asarray(part, np.float64) for part in paths.a)          # [rx, rx antenna, tx, tx antenna, path]
    sionna_db = 10 * np.log10((re ** 2 + im ** 2).reshape(len(rx), -1).sum(1))

    dipole = EndAntenna(AntennaPattern("dipole"))
    room = floor_room(antennas=RoomAntennas(dipole, dipole))      # the floor at z = 0 is below every direct path
    axes = LinkAxes(np.tile(rotation(*tx_turn)[:, 2], (len(rx), 1)), np.stack([rotation(*t)[:, 2] for t in rx_turns]))
    ours = {}
    for name, link_axes in (("turned", axes), ("vertical", None)):
        traced = room.links(tx, rx, np.full(len(rx), FREQ), axes=link_axes)
        direct = traced.select_paths(traced.paths.order == 0)
        ours[name] = 10 * np.log10(direct.power(METAL)[:, 0].numpy())
    np.testing.assert_allclose(ours["turned"], sionna_db, atol=0.01)
    assert np.abs(ours["vertical"] - sionna_db).max() > 1.0
