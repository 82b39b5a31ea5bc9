"""Objects as boxes in `rfir structure` (rfir_stages.geom.object_boxes): boxes recovered from photo-like Gaussians
of a room with two boxes (one turned in yaw) and a round blob, which stays free Gaussians; a desk becomes its top;
the setting that keeps the segments as Gaussians."""
from __future__ import annotations

import numpy as np
import pytest

from rfir_core.errors import ConfigError

ROOM = (6.0, 5.0, 2.8)
# (centre x, y [m], size along its own u, v and up [m], yaw [deg]): standing on the floor
BOXES = [((2.0, 1.5), (1.0, 0.6, 0.8), 0.0), ((4.2, 3.2), (0.9, 0.5, 0.5), 25.0)]
BLOB = ((1.5, 3.6, 1.3), 0.3)          # centre [m], radius [m]: a round thing hanging in the room
NOISE_M, TILT_DEG, DENSITY = 0.015, 3.0, 400.0


def _rect(rng, corner, su, sv, density):
    """Photo-like Gaussians on the rectangle corner + [0, 1] su + [0, 1] sv: (points [n, 3], normals [n, 3])."""
    su, sv = np.asarray(su, float), np.asarray(sv, float)
    normal = np.cross(su, sv) / np.linalg.norm(np.cross(su, sv))
    k = max(3, int(density * np.linalg.norm(su) * np.linalg.norm(sv)))
    a, b = rng.random((2, k))
    x = np.asarray(corner, float) + np.outer(a, su) + np.outer(b, sv)
    return x, np.broadcast_to(normal, x.shape).copy()


def _box_faces(centre_xy, size, yaw_deg, z0=0.0):
    """The box's top and four sides as (corner, side_u, side_v): its bottom, on the floor, is never seen."""
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    u, v, up = np.array([c, s, 0.0]), np.array([-s, c, 0.0]), np.array([0.0, 0.0, 1.0])
    lu, lv, lz = size
    base = np.array([*centre_xy, z0]) - 0.5 * lu * u - 0.5 * lv * v
    return [(base + lz * up, lu * u, lv * v), (base, lu * u, lz * up), (base + lv * v, lu * u, lz * up),
            (base, lv * v, lz * up), (base + lu * u, lv * v, lz * up)]


def _room_faces():
    lx, ly, lz = ROOM
    return [((0, 0, 0), (lx, 0, 0), (0, ly, 0)), ((0, 0, lz), (lx, 0, 0), (0, ly, 0)),
            ((0, 0, 0), (lx, 0, 0), (0, 0, lz)), ((0, ly, 0), (lx, 0, 0), (0, 0, lz)),
            ((0, 0, 0), (0, ly, 0), (0, 0, lz)), ((lx, 0, 0), (0, ly, 0), (0, 0, lz))]


def _fields(rng, rects, blob=True, room_density=60.0):
    """Scene fields: the room's surfaces at room_density (0: no room), the rectangles rects at DENSITY per m^2,
    and the blob's sphere; positions scattered NOISE_M along the normal, normals tilted by TILT_DEG. Returns
    (fields, [G] bool of the blob's Gaussians)."""
    room = [_rect(rng, *r, room_density) for r in _room_faces()] if room_density > 0 else []
    parts = room + [_rect(rng, *r, DENSITY) for r in rects]
    x, n = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
    in_blob = np.zeros(len(x), bool)
    if blob:
        centre, radius = BLOB
        k = int(DENSITY * 4 * np.pi * radius ** 2)
        d = rng.normal(size=(k, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        x, n = np.concatenate([x, np.asarray(centre) + radius * d]), np.concatenate([n, d])
        in_blob = np.concatenate([in_blob, np.ones(k, bool)])
    x = x + n * rng.normal(0.0, NOISE_M, (len(x), 1))
    tilt = rng.normal(0.0, np.radians(TILT_DEG) / np.sqrt(2), (len(x), 3))
    n = n + np.cross(tilt, n)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    g = len(x)
    return {"gaussians/means": x, "gaussians/normals": n, "gaussians/log_scales": np.log(np.full((g, 3), 0.02)),
            "gaussians/rotations": np.tile([1.0, 0, 0, 0], (g, 1)), "gaussians/opacities": np.ones(g),
            "gaussians/colors": rng.uniform(0.3, 0.7, (g, 3))}, in_blob


def _write(path, fields):
    from rfir_core.artifacts import write_artifact

    write_artifact(path, "scene", fields)
    return path


def _match(box, centre_xy, size, yaw_deg):
    """(centre error [m], size errors [3] as shares, yaw error [deg]) of a found box against a true one, the found
    box's u and v swapped when its yaw is the true one's turned by 90 degrees."""
    true_centre = np.array([*centre_xy, 0.5 * size[2]])
    found = np.array(box.size_m, float)
    gap = (box.yaw_deg - yaw_deg + 45.0) % 90.0 - 45.0
    if abs(((box.yaw_deg - yaw_deg) % 180.0) - 90.0) < 45.0:
        found = found[[1, 0, 2]]
    return np.linalg.norm(box.centre - true_centre), np.abs(found / np.asarray(size) - 1.0), abs(gap)


@pytest.fixture(scope="module")
def boxes_run(tmp_path_factory):
    from rfir_core.artifacts import read_artifact
    from rfir_stages.geom.structure import run

    tmp = tmp_path_factory.mktemp("boxes")
    rects = [f for centre, size, yaw in BOXES for f in _box_faces(centre, size, yaw)]
    fields, in_blob = _fields(np.random.default_rng(5), rects)
    result = run(_write(tmp / "room.h5", fields), tmp / "boxes.h5", {"insets": False})
    return result, read_artifact(tmp / "boxes.h5", "scene"), fields, in_blob


def test_two_boxes_recovered_one_turned_in_yaw(boxes_run):
    result, _, _, _ = boxes_run
    assert len(result.boxes) == 2, [(b.size_m, b.centre) for b in result.boxes]
    for centre, size, yaw in BOXES:
        errors = [_match(b, centre, size, yaw) for b in result.boxes]
        d_centre, d_size, d_yaw = min(errors, key=lambda e: e[0])
        assert d_centre < 0.05, (centre, errors)
        assert (d_size < 0.10).all(), (size, d_size)
        assert d_yaw < 3.0, (yaw, d_yaw)
    assert all(b.on_floor for b in result.boxes)


def test_boxes_faces_written_and_blob_left_free(boxes_run):
    result, art, fields, in_blob = boxes_run
    names = [str(n) for n in art.attrs["label_names"]]
    labels, x, n = art.data["gaussians/labels"], art.data["gaussians/means"], art.data["gaussians/normals"]
    for box in result.boxes:
        on = labels == names.index(box.name)
        axes = box.axes
        local = (x[on] - box.centre) @ axes.T
        # every surfel lies on one of the box's faces, with that face's normal; five faces, the bottom left out
        on_face = np.isclose(np.abs(local), 0.5 * box.size_m, atol=1e-6)
        assert on_face.any(1).all()
        normals = np.unique(np.round(n[on] @ axes.T, 6), axis=0)
        assert len(normals) == 5 and not (normals[:, 2] < -0.5).any()
        assert np.isclose((np.pi * np.prod(np.exp(art.data["gaussians/log_scales"][on][:, :2]), axis=1)).sum(),
                          2 * box.size_m[2] * (box.size_m[0] + box.size_m[1]) + box.size_m[0] * box.size_m[1], rtol=1e-6)
    # the blob: no box, its Gaussians free (label -1), as they came in
    centre, radius = BLOB
    near_blob = np.linalg.norm(x - np.asarray(centre), axis=1) < radius + 0.1
    assert (labels[near_blob] == -1).all() and near_blob.sum() == in_blob.sum()
    assert result.num_on_shell + result.num_in_objects + result.num_free == len(fields["gaussians/means"])


def test_a_desk_is_its_top_not_a_block_to_the_floor():
    """A desk (a 3 cm top at 0.75 m on four 5 cm legs): one box is a plate at the top's height, over the top's
    extent; the others are legs (thin posts): no box blocks the space under the desk."""
    from rfir_stages.geom.object_boxes import BoxSettings, find_boxes
    from rfir_stages.geom.planes import footprint_areas_m2, votes_and_radii

    rng = np.random.default_rng(8)
    rects = _box_faces((2.0, 2.0), (1.2, 0.6, 0.03), 0.0, z0=0.72)
    for lx in (1.45, 2.5):
        for ly in (1.75, 2.2):
            rects += _box_faces((lx, ly), (0.05, 0.05, 0.72), 0.0)[1:]
    fields, _ = _fields(rng, rects, blob=False, room_density=0.0)
    x, n = fields["gaussians/means"], fields["gaussians/normals"]
    votes, radii = votes_and_radii(footprint_areas_m2(fields["gaussians/log_scales"]), len(x))
    boxes = find_boxes(x, n, votes, radii / np.sqrt(2), np.zeros(len(x), int), 0.0, [np.array([1.0, 0, 0])],
                       BoxSettings(), distance_m=0.06, normal_deg=25.0, min_points=20)
    plates = [b for b in boxes if b.size_m[:2].min() > 0.3]
    assert len(plates) == 1
    top = plates[0]
    # the rest are legs: thin posts at the four corners, nothing filling the space under the top
    legs = [b for b in boxes if b is not top]
    assert all(b.size_m[:2].max() < 0.1 for b in legs) and len(legs) <= 8
    assert abs(top.centre[2] - 0.735) < 0.03 and top.size_m[2] <= 0.07 and not top.on_floor
    sizes = sorted(top.size_m[:2])
    assert sizes == pytest.approx([0.6, 1.2], rel=0.1)


def test_yaw_snaps_to_the_walls_only_when_near_them():
    from rfir_stages.geom.object_boxes import segment_yaw

    rng = np.random.default_rng(1)
    for yaw, walls, expected in ((3.0, [0.0], 0.0), (20.0, [0.0], 20.0), (33.0, [30.0], 30.0)):
        t = np.radians(yaw)
        local = rng.random((2000, 2)) * [1.0, 0.4]
        xy = local @ np.array([[np.cos(t), np.sin(t)], [-np.sin(t), np.cos(t)]])
        assert segment_yaw(xy, np.ones(len(xy)), walls, 5.0) == pytest.approx(expected, abs=0.5)


def test_keep_leaves_the_segments_as_gaussians_and_bad_settings_are_refused(tmp_path):
    from rfir_core.artifacts import read_artifact
    from rfir_stages.geom.structure import run

    rects = [f for centre, size, yaw in BOXES for f in _box_faces(centre, size, yaw)]
    fields, _ = _fields(np.random.default_rng(6), rects, blob=False)
    scene = _write(tmp_path / "room.h5", fields)
    result = run(scene, tmp_path / "keep.h5", {"insets": False, "objects": "keep"})
    art = read_artifact(tmp_path / "keep.h5", "scene")
    names = [str(n) for n in art.attrs["label_names"]]
    assert result.boxes == [] and result.num_objects == sum(name.startswith("object_") for name in names) >= 2
    with pytest.raises(ConfigError, match="objects"):
        run(scene, tmp_path / "bad.h5", {"objects": "cubes"})
    with pytest.raises(ConfigError, match="box_fill"):
        run(scene, tmp_path / "bad.h5", {"box_fill": 1.5})


def test_without_tiling_the_boxes_gaussians_are_projected_onto_their_faces(tmp_path):
    from rfir_core.artifacts import read_artifact
    from rfir_stages.geom.structure import run

    rects = [f for centre, size, yaw in BOXES for f in _box_faces(centre, size, yaw)]
    fields, _ = _fields(np.random.default_rng(7), rects, blob=False)
    result = run(_write(tmp_path / "room.h5", fields), tmp_path / "proj.h5", {"insets": False, "tile_shell": False})
    art = read_artifact(tmp_path / "proj.h5", "scene")
    names = [str(n) for n in art.attrs["label_names"]]
    labels, x, n = art.data["gaussians/labels"], art.data["gaussians/means"], art.data["gaussians/normals"]
    assert len(labels) == len(fields["gaussians/means"]) and len(result.boxes) == 2
    for box in result.boxes:
        on = labels == names.index(box.name)
        assert on.sum() == len(box.members) > 100
        local = (x[on] - box.centre) @ box.axes.T
        face = np.isclose(np.abs(local), 0.5 * box.size_m, atol=1e-9)
        assert face.any(1).all()
        # each Gaussian's normal is its face's: along the one axis it lies on the face of
        along = np.abs(n[on] @ box.axes.T)
        assert np.allclose(along[face], 1.0, atol=1e-9)
