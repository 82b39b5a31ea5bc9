"""Scene geometry, PLY output, antenna patterns, settings and measurement effects (no Sionna)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from rfir_core.errors import ConfigError
from rfir_core.physics.antennas import Antenna, horn_boresight_gain, horn_exponent, horn_gain
from rfir_stages.simulate.measurement import MeasurementEffects, apply_measurement_effects
from rfir_stages.simulate.scenes import SCENES, box, build_scene, write_meshes
from rfir_stages.simulate.settings import parse_settings

FAST_SCENES = [s for s in SCENES if s != "car"]  # car needs sionna-rt's package data


def _outward(vertices, faces, centre):
    v = vertices[faces]
    n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
    return np.einsum("ij,ij->i", n, v.mean(1) - centre) > 0


def test_box_is_closed_and_outward():
    v, f = box((0, 0, 0), (1, 2, 3))
    assert v.shape == (24, 3) and f.shape == (12, 3)
    assert _outward(v, f, np.array([0.5, 1.0, 1.5])).all()
    # closed: the signed volume equals the box volume
    tri = v[f]
    vol = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6
    assert vol == pytest.approx(6.0)


@pytest.mark.parametrize("name", FAST_SCENES)
def test_scene_objects_are_well_formed(name):
    spec = build_scene(name)
    assert spec.kind in ("room", "object")
    names = [o.name for o in spec.objects]
    assert len(set(names)) == len(names)
    for i, o in enumerate(spec.objects):
        assert o.label == i
        assert o.vertices.dtype == np.float64 and o.vertices.shape[1] == 3
        assert o.faces.dtype == np.int32 and o.faces.max() < len(o.vertices)
        assert np.all(np.linalg.norm(np.cross(*(o.vertices[o.faces][:, k] - o.vertices[o.faces][:, 0]
                                                 for k in (1, 2))), axis=1) > 0), "degenerate face"
        assert len(o.color) == 3 and all(0 <= c <= 1 for c in o.color)
    if spec.objects:
        allv = np.concatenate([o.vertices for o in spec.objects])
        np.testing.assert_allclose(spec.bounds, [allv.min(0), allv.max(0)])


def test_classroom_layout():
    spec = build_scene("classroom")
    np.testing.assert_allclose(spec.bounds, [[0, 0, 0], [9, 7, 3]])
    mats = {o.name: o.radio_material for o in spec.objects}
    assert mats["whiteboard"] == "metal" and mats["door"] == "wood" and mats["floor"] == "concrete"
    assert sum(n.startswith("window") for n in mats) >= 2 and all(mats[n] == "glass" for n in mats if n.startswith("window_"))
    assert sum(n.startswith("desk") for n in mats) >= 8 and sum(n.startswith("chair") for n in mats) >= 8
    assert spec.num_faces < 5000
    # room shell faces point into the room
    centre = np.array([4.5, 3.5, 1.5])
    for o in spec.objects:
        if o.name.startswith(("wall", "floor", "ceiling")):
            assert not _outward(o.vertices, o.faces, centre).any(), o.name


def test_objects_are_centred_and_sized():
    h = build_scene("h-target")
    np.testing.assert_allclose(h.bounds, [[-0.25, -0.1, -0.3], [0.25, 0.1, 0.3]])
    assert h.objects[0].radio_material == "metal"
    lego = build_scene("lego")
    ext = lego.bounds[1] - lego.bounds[0]
    assert 0.3 < ext.max() < 0.5
    np.testing.assert_allclose(lego.bounds[0] + lego.bounds[1], 0, atol=1e-12)


def test_trio_has_three_materials_and_a_closed_dihedral_corner():
    trio = build_scene("trio")
    assert [(o.name, o.radio_material) for o in trio.objects] == [("dihedral", "metal"), ("block", "wood"),
                                                                   ("pane", "glass")]
    np.testing.assert_allclose(trio.bounds[0] + trio.bounds[1], 0, atol=1e-12)
    sheets = trio.objects[0].vertices
    # the two sheets meet along one vertical edge: both reach the same corner x = y = min
    lo = sheets.min(0)
    assert np.any(np.all(np.isclose(sheets[:, :2], lo[:2]), axis=1))
    assert trio.objects[0].thickness_m == pytest.approx(0.003) and trio.objects[2].thickness_m == pytest.approx(0.006)


def test_car_from_sionna():
    pytest.importorskip("sionna.rt")
    car = build_scene("car")
    assert car.num_faces == 20
    np.testing.assert_allclose(car.bounds[0] + car.bounds[1], 0, atol=1e-12)
    assert (car.bounds[1] - car.bounds[0]).max() == pytest.approx(0.45)


def test_write_meshes_round_trip(tmp_path):
    spec = build_scene("h-target")
    paths = write_meshes(spec, tmp_path)
    assert [p.name for p in paths] == ["h_target.ply", "h-target_gt.ply"]
    labels = json.loads((tmp_path / "labels.json").read_text())
    assert labels["objects"][0]["radio_material"] == "metal"
    data = paths[-1].read_bytes()
    head, body = data.split(b"end_header\n", 1)
    assert b"property int label" in head
    nv = len(spec.objects[0].vertices)
    verts = np.frombuffer(body[: nv * 16], dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("l", "<i4")])
    np.testing.assert_allclose(verts["x"], spec.objects[0].vertices[:, 0], atol=1e-6)
    assert (verts["l"] == 0).all()


def test_horn_pattern():
    q = horn_exponent(40.0)
    assert horn_gain(math.radians(20.0)) == pytest.approx(0.5 * horn_boresight_gain(), rel=1e-9)
    assert horn_boresight_gain(40.0) == pytest.approx(2 * (q + 1))
    # normalised: integral of G over the sphere = 4 pi
    th = np.linspace(0, math.pi, 20001)
    integral = np.trapezoid(horn_gain(th) * np.sin(th), th) * 2 * math.pi
    assert integral == pytest.approx(4 * math.pi, rel=1e-4)
    ant = Antenna("horn", (0, 1, 0))
    assert ant.gain(np.array([[0, 1, 0], [0, -1, 0]])).tolist() == [pytest.approx(horn_boresight_gain()), 0.0]


def test_settings_quick_and_errors():
    s = parse_settings(None, quick=True)
    assert s.quick and s.aspect_step_deg == 30.0 and s.rx_grid == [5, 4]
    full = parse_settings(None, quick=False)
    assert full.aspect_step_deg == 1.0 and full.ranges_m == [2.0, 2.5, 3.0, 4.0, 4.5, 5.0]
    assert full.tx_grid[0] * full.tx_grid[1] == 24 and full.rx_grid[0] * full.rx_grid[1] == 440
    with pytest.raises(ConfigError):
        parse_settings({"physics": {"scattering_pattern": "mirror"}})
    with pytest.raises(ConfigError):
        parse_settings({"tasks": ["radar"]})


def test_measurement_effects():
    rng = np.random.default_rng(0)
    power = np.full((20000, 3), 1e-6)
    channel = np.sqrt(power) * np.exp(1j * 0.3)
    freqs = np.array([5.72e9, 5.74e9, 5.76e9])
    eff = MeasurementEffects(noise_db=1.0, gain_offset_db=2.0, ripple_db=0.5, ripple_period_hz=80e6)
    gain_db, ch = apply_measurement_effects(power, channel, freqs, eff, rng)
    np.testing.assert_allclose(10 * np.log10(np.abs(ch) ** 2), gain_db, atol=1e-9)
    np.testing.assert_allclose(np.angle(ch), 0.3, atol=1e-12)
    mean = gain_db.mean(0) - (-60.0)
    np.testing.assert_allclose(mean, 2.0 + 0.5 * np.sin(2 * np.pi * (freqs - freqs[0]) / 80e6), atol=0.1)
    assert gain_db.std(0).mean() == pytest.approx(1.0, abs=0.1)
    clipped, _ = apply_measurement_effects(np.zeros((2, 1)), np.zeros((2, 1), complex), freqs[:1],
                                           MeasurementEffects(floor_db=-200.0), rng)
    assert (clipped == -200.0).all()


def test_default_photo_counts_follow_the_scene_kind():
    from rfir_stages.simulate import build_scene
    from rfir_stages.simulate.stage import view_count

    assert view_count(build_scene("lego").kind, 0) == 60
    assert view_count(build_scene("classroom").kind, 0) == 120
    assert view_count("object", 24) == 24


def test_lego_bricks_never_share_volume():
    """Two bricks of a layer that overlap put coincident, co-facing faces into the mesh, which the
    physical-optics solver lights and integrates twice (one surface, twice the current)."""
    from rfir_stages.simulate.scenes import LEGO_LAYOUT

    cells = {}
    for n, (i, j, k, nx, ny, _) in enumerate(LEGO_LAYOUT):
        for a in range(i, i + nx):
            for b in range(j, j + ny):
                assert (a, b, k) not in cells, f"brick {n} overlaps brick {cells[(a, b, k)]} at stud ({a}, {b}), layer {k}"
                cells[(a, b, k)] = n
    # every brick above the first layer rests on a brick below it
    for n, (i, j, k, nx, ny, _) in enumerate(LEGO_LAYOUT):
        if k:
            assert any((a, b, k - 1) in cells for a in range(i, i + nx) for b in range(j, j + ny)), n


def _signed_volume(objects, apex):
    """m^3: the summed signed volumes of the tetrahedra from `apex` (3,) to the triangles of `objects`: the
    enclosed volume (negative when the normals point in) whatever the apex when the triangles close a surface."""
    tri = np.concatenate([o.vertices[o.faces] for o in objects]) - np.asarray(apex, float)
    return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6)


def test_office_layout():
    """The office: an L-shaped shell closed by its walls, windows and door, normals into the room; a glass
    partition from wall to core, floor to ceiling, with a door gap; metal furniture; antennas only inside the L."""
    from rfir_stages.simulate.scenes import OFFICE_AREAS, OFFICE_GLASS_X_M
    from rfir_stages.simulate.stage import rssi_grids

    spec = build_scene("office")
    by_name = {o.name: o for o in spec.objects}
    lz = spec.bounds[1, 2]
    np.testing.assert_allclose(spec.bounds, [[0, 0, 0], [10, 8, 3]])
    areas = list(OFFICE_AREAS.values())
    footprint = sum((x1 - x0) * (y1 - y0) for x0, x1, y0, y1 in areas)
    assert footprint < 0.85 * 10 * 8  # not the bounding rectangle: an L
    shell = [o for n, o in by_name.items() if n in ("floor", "ceiling", "door") or n.startswith(("wall_", "window_"))]
    # closed: a hole (a missing window pane) or a face turned the wrong way changes the enclosed volume
    for apex in ([0.0, 0.0, 0.0], [2.3, 1.7, 1.1], [13.0, -4.0, 6.0]):  # a hole changes the volume with the apex
        assert _signed_volume(shell, apex) == pytest.approx(-footprint * lz, rel=1e-9)
    for o in shell:
        assert o.radio_material == ("wood" if o.name == "door" else "glass" if o.name.startswith("window_") else "concrete")
    assert sum(n.startswith("window_") for n in by_name) >= 3

    glass = by_name["glass_partition"]
    assert glass.radio_material == "glass" and glass.visual == "glass" and glass.thickness_m < 0.02
    np.testing.assert_allclose(glass.vertices[:, 0], OFFICE_GLASS_X_M)
    main = OFFICE_AREAS["main"]
    np.testing.assert_allclose([glass.vertices[:, 1].min(), glass.vertices[:, 1].max()], main[2:])
    np.testing.assert_allclose([glass.vertices[:, 2].min(), glass.vertices[:, 2].max()], [0.0, lz])
    height = main[3] - main[2]
    assert 0.6 * height * lz < glass.area_m2() < height * lz  # a door gap, most of the wall glass

    metal = [o for o in spec.objects if o.radio_material == "metal"]
    assert len(metal) >= 3 and all(o.visual == "metal" for o in metal)
    assert any(o.vertices[:, 2].max() >= 1.9 for o in metal)  # a tall one (cupboard, shelving)
    assert sum(n.startswith("desk_") for n in by_name) >= 4

    def inside_l(p):
        return np.any([(x0 < p[:, 0]) & (p[:, 0] < x1) & (y0 < p[:, 1]) & (p[:, 1] < y1) for x0, x1, y0, y1 in areas], 0)

    for o in spec.objects:  # every object stands inside the L (walls on its edge)
        centre = 0.5 * (o.vertices.min(0) + o.vertices.max(0))
        if not o.name.startswith(("wall_", "window_", "floor", "ceiling", "door")):
            assert inside_l(centre[None])[0], o.name
    s = parse_settings(None, scene="office")
    tx, rx, tx_clear, rx_clear = rssi_grids(spec, s)
    assert (~inside_l(tx) <= ~tx_clear).all() and (~inside_l(rx) <= ~rx_clear).all()  # outside the L: dropped
    assert (~inside_l(rx)).sum() > 0.1 * len(rx)  # the grid does reach the core, and those points go
    assert 10 <= tx_clear.sum() <= 20 and 200 <= rx_clear.sum() <= 600
