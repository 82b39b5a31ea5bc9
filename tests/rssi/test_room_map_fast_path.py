"""The room model's fast path for radio maps equals a per-link reference computation.

A map traces every (link, patch sequence) at once and keeps the surfaces crossed from each receiver to
the diffuse cells for the next transmitter (room_paths.reflection_paths, room_diffuse.CellCrossings).
On the reduced room (a partition with a doorway, a table) both must give what a link traced alone on
a fresh model gives, to 1e-9 relative: the reflection points from a plain per-link, per-sequence
image method here, and the received power of a second transmitter's map against each link traced
alone with nothing kept (1e-9 relative in power is 4e-9 dB, the issue's budget for the fast path being
0.01 dB).
"""
import itertools

import numpy as np
import pytest
import torch

from rfir_stages.model.physical import MaterialValues
from rfir_stages.model.room import RoomLinks
from rfir_stages.model.room_diffuse import CellCrossings, diffuse_terms
from rfir_stages.model.room_paths import reflection_paths, trace_room_paths

from .helpers import ROOM, room_geometry

F = 2.4e9


@pytest.fixture(scope="module")
def room():
    return room_geometry(0.3)[0]


def _grid(z=1.0, n=(7, 5)):
    lx, ly, _ = ROOM
    return np.array([[x, y, z] for x in np.linspace(0.25, lx - 0.25, n[0]) for y in np.linspace(0.25, ly - 0.25, n[1])])


def _per_link_image_method(tx, rx, patches, cand, order, min_m=1e-4):
    """{(link, patch sequence): reflection points [order, 3]}: each link and each sequence on its own."""
    nrm, pnt = patches.normal, patches.point
    out = {}
    for m, (t, r) in enumerate(zip(tx, rx)):
        for seq in itertools.product(cand, repeat=order):
            if any(a == b or (abs(nrm[a] @ nrm[b]) > 0.999 and abs((pnt[b] - pnt[a]) @ nrm[a]) < 1e-3)
                   for a, b in zip(seq[:-1], seq[1:])):
                continue
            images, ok = [t], True
            for p in seq:
                side = (images[-1] - pnt[p]) @ nrm[p]
                if abs(side) <= min_m:
                    ok = False
                    break
                images.append(images[-1] - 2.0 * side * nrm[p])
            if not ok:
                continue
            x, pts = r, []
            for k in range(order - 1, -1, -1):
                p = seq[k]
                if ((x - pnt[p]) @ nrm[p]) * ((images[k] - pnt[p]) @ nrm[p]) <= min_m ** 2:
                    ok = False
                    break
                a, b = images[k + 1], x
                da, db = (a - pnt[p]) @ nrm[p], (b - pnt[p]) @ nrm[p]
                x = a + da / (da - db) * (b - a)
                if not patches.contains(np.array([p]), x[None])[0]:
                    ok = False
                    break
                pts.insert(0, x)
            if ok:
                out[(m, tuple(int(p) for p in seq))] = np.array(pts)
    return out


@pytest.mark.parametrize("shared", [False, True])
@pytest.mark.parametrize("order", [1, 2])
def test_reflection_paths_equal_the_per_link_image_method(room, order, shared):
    """shared: 3 transmitters for 12 links, interleaved (maps: the images are built once per transmitter)."""
    rng = np.random.default_rng(order)
    lx, ly, lz = ROOM
    tx = rng.uniform([0.2, 0.2, 1.2], [lx - 0.2, ly - 0.2, lz - 0.2], (12, 3))
    if shared:
        tx = tx[np.arange(12) % 3]
    rx = rng.uniform([0.2, 0.2, 0.3], [lx - 0.2, ly - 0.2, 1.6], (12, 3))
    patches = room.patches
    cand = np.flatnonzero(patches.area >= (0.0 if order == 1 else 1.0))
    link, seq, pts = reflection_paths(tx, rx, patches, cand, order)
    want = _per_link_image_method(tx, rx, patches, cand, order)
    got = {(int(m), tuple(int(p) for p in s)): c for m, s, c in zip(link, seq, pts)}
    assert len(want) > (20 if order == 1 else 5)          # the room has paths of this order to compare
    assert set(got) == set(want)
    for key, c in want.items():
        np.testing.assert_allclose(got[key], c, rtol=0, atol=1e-12)


def _materials(n):
    return MaterialValues(torch.linspace(2.0, 6.0, n, dtype=torch.float64), torch.linspace(0.01, 0.3, n, dtype=torch.float64),
                          0.0, torch.full((n,), 0.3, dtype=torch.float64), torch.linspace(0.03, 0.2, n, dtype=torch.float64))


class _FullRows(CellCrossings):
    """Every cell traced from every point, whatever a call needs (the reference for the fast path's rows)."""

    def __call__(self, points, need=None):
        return super().__call__(points)


def test_a_second_transmitters_map_with_kept_receivers_equals_each_link_traced_alone(room):
    """The receivers' rows traced where the first map needs them, completed for the second."""
    room.cell_crossings.clear()
    rx = _grid()
    mats = _materials(room.num_materials)
    freq = np.full(len(rx), F)
    room.links(np.broadcast_to([1.0, 1.0, 2.0], rx.shape), rx, freq)             # a first map keeps the receivers
    kept = len(room.cell_crossings)
    tx_b = np.array([3.1, 2.2, 1.8])
    fast_links = room.links(np.broadcast_to(tx_b, rx.shape), rx, freq)
    fast = fast_links.power(mats)[:, 0].numpy()
    assert len(room.cell_crossings) == kept + 1                               # only the new transmitter traced
    assert len(fast_links.diffuse.obstructed.link) > 0                        # some cells lie behind the partition
    s = room.settings
    ref = []
    for r in rx:                                                                    # each link alone, nothing kept
        t1, r1 = tx_b[None], r[None]
        paths = trace_room_paths(t1, r1, np.full(1, F), room.patches, room.provider, polarisation=s.polarisation,
                                 max_order=s.max_order, higher_order_min_area_m2=s.higher_order_min_area_m2,
                                 third_order_min_area_m2=s.third_order_min_area_m2,
                                 max_interactions=s.max_interactions)
        full = _FullRows(room.cells, room.patches, room.provider)
        diff = diffuse_terms(t1, r1, np.full(1, F), room.cells, room.material_of_patch, room.num_materials, full)
        one = RoomLinks(paths, diff, torch.as_tensor(room.material_of_patch), room.num_materials)
        ref.append(one.power(mats)[0, 0].item())
    ref = np.array(ref)
    assert np.ptp(10 * np.log10(ref)) > 10.0                  # the map spans the partition's shadow and the open side
    np.testing.assert_allclose(fast, ref, rtol=1e-9, atol=0)


def test_the_models_stored_map_receivers_give_the_map_traced_afresh(tmp_path, monkeypatch):
    """rf-fit keeps the surfaces crossed from the default map's receivers in the model; predicting with those rows equals
    tracing them again, and a model whose Gaussians moved (an edit) does not use them. The model's stored
    surfel areas are used while its Gaussians are the fitted ones, and equal the areas computed again."""
    import rfir_stages.model.room as room_module
    from rfir_stages.model.surfels import surfel_areas
    from typer.testing import CliRunner

    from rfir_core.artifacts import read_artifact, write_artifact
    from rfir_cli.main import app
    from rfir_stages.model.room import RoomPredictor
    from rfir_stages.predict.rssi import rssi_defaults
    from rfir_stages.predict.rssi_checks import floor_grid

    from .helpers import write_measurements, write_scene

    write_scene(tmp_path / "scene.h5", spacing_m=0.3)
    write_measurements(tmp_path / "meas.h5")
    r = CliRunner().invoke(app, ["--set", "rf_fit.physical.iterations=4", "--set", "rf_fit.physical.start_iterations=2",
                                 "rf-fit", str(tmp_path / "scene.h5"), str(tmp_path / "meas.h5"), "-o",
                                 str(tmp_path / "rf.h5")])
    assert r.exit_code == 0, r.output
    rf = read_artifact(tmp_path / "rf.h5", "rf")
    with monkeypatch.context() as m:
        m.setattr(room_module, "surfel_areas", None)               # the stored areas, not computed again
        pred = RoomPredictor(rf)
    g = pred.geom
    np.testing.assert_array_equal(pred.room.areas.numpy(),
                                  surfel_areas(g.means, g.log_scales, g.rotations, g.normals).numpy())
    means = pred.geom.means.numpy()
    rx = floor_grid((means.min(0), means.max(0)), *rssi_defaults()["grid"])
    assert len(pred.room.cell_crossings) == len(rx)          # every map receiver kept
    tx = np.broadcast_to([3.1, 2.2, 1.8], rx.shape)
    kept = pred.path_gain_db(tx, rx)
    assert len(pred.room.cell_crossings) == len(rx) + 1      # the transmitter alone was traced
    pred.room.cell_crossings.clear()
    np.testing.assert_allclose(10 ** (kept / 10), 10 ** (pred.path_gain_db(tx, rx) / 10), rtol=1e-9, atol=0)
    data = dict(rf.data)
    data["gaussians/means"] = data["gaussians/means"] + np.array([0.0, 0.0, 1e-6])
    write_artifact(tmp_path / "moved.h5", "rf", data, attrs=rf.attrs, free=rf.free_for_write())
    moved = read_artifact(tmp_path / "moved.h5", "rf")
    assert len(RoomPredictor(moved).room.cell_crossings) == 0
    with monkeypatch.context() as m, pytest.raises(TypeError):
        m.setattr(room_module, "surfel_areas", None)               # moved Gaussians: the areas are computed again
        RoomPredictor(moved)
    assert pred.room.settings.patch_extent == "tiles"
    free = rf.free_for_write()
    del free["model"]["@attrs"]["room.patch_extent"]                 # a model written before extents were stored
    write_artifact(tmp_path / "old.h5", "rf", rf.data, attrs=rf.attrs, free=free)
    assert RoomPredictor(read_artifact(tmp_path / "old.h5", "rf")).room.settings.patch_extent == "disks"
