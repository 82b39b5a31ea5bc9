"""`rfir structure`: the planes found in Gaussians sampled from a known box room with photo-like noise match the room
(rfir_stages.geom.structure, planes.py, room_shell.py)."""
from __future__ import annotations

import numpy as np
import pytest

from rfir_core.errors import InputFileError, StageError

ROOM = (6.0, 4.0, 2.8)                 # x, y, z size [m]
DOOR = (1.0, 1.9, 0.0, 2.0)            # in the y = 4 wall: x from, x to, z from, z to [m]
HIDDEN = (0.5, 3.5, 0.0, 0.3)          # the x = 6 wall unseen along the floor (behind furniture): y, z ranges [m]
TABLE = ((2.5, 1.5, 0.0), (3.7, 2.3, 0.75))
BOARD = (1.0, 3.0, 1.0, 2.0)           # on the x = 0 wall: y from, y to, z from, z to [m] ...
PLASTER, BOARD_RGB = (0.85, 0.83, 0.78), (0.93, 0.94, 0.95)   # ... whiteboard against plaster, as the classroom's
OFFSET_NOISE_M = 0.025                 # photo Gaussians scatter 2-3 cm along the normal ...
TILT_NOISE_DEG = 4.0                   # ... their normals some degrees


def _patch(rng, corner, side_u, side_v, normal, density, hole=None):
    """Points [n, 3] and normals [n, 3] uniform on the rectangle corner + [0,1] side_u + [0,1] side_v; hole: (u0, u1,
    v0, v1) in metres along the sides left empty."""
    side_u, side_v = np.asarray(side_u, float), np.asarray(side_v, float)
    lu, lv = np.linalg.norm(side_u), np.linalg.norm(side_v)
    n = int(density * lu * lv)
    a, b = rng.random(n) * lu, rng.random(n) * lv
    if hole is not None:
        keep = ~((a >= hole[0]) & (a <= hole[1]) & (b >= hole[2]) & (b <= hole[3]))
        a, b = a[keep], b[keep]
    pts = np.asarray(corner, float) + np.outer(a / lu, side_u) + np.outer(b / lv, side_v)
    return pts, np.broadcast_to(np.asarray(normal, float), pts.shape).copy()


def sampled_room(rng, density=150.0, tilt_deg=0.0):
    """Gaussian fields of a box room (ROOM) with a door opening, a strip of wall unseen along the floor, a table,
    a ceiling seen only near the walls, a whiteboard on the x = 0 wall (another colour), photo noise and 2 %
    outliers; the whole room turned by tilt_deg about x. Returns (fields, true rotation [3, 3])."""
    lx, ly, lz = ROOM
    parts = [
        _patch(rng, (0, 0, 0), (lx, 0, 0), (0, ly, 0), (0, 0, 1), density),                 # floor
        _patch(rng, (0, 0, lz), (lx, 0, 0), (0, ly, 0), (0, 0, -1), density * 0.3,           # ceiling: a patch unseen
               hole=(1.0, 5.0, 0.8, 3.2)),
        _patch(rng, (0, 0, 0), (0, ly, 0), (0, 0, lz), (1, 0, 0), density),                 # wall x = 0
        _patch(rng, (lx, 0, 0), (0, ly, 0), (0, 0, lz), (-1, 0, 0), density, hole=HIDDEN),  # wall x = 6
        _patch(rng, (0, 0, 0), (lx, 0, 0), (0, 0, lz), (0, 1, 0), density),                 # wall y = 0
        _patch(rng, (0, ly, 0), (lx, 0, 0), (0, 0, lz), (0, -1, 0), density, hole=DOOR),    # wall y = 4, a door
    ]
    (x0, y0, _), (x1, y1, z1) = TABLE
    parts.append(_patch(rng, (x0, y0, z1), (x1 - x0, 0, 0), (0, y1 - y0, 0), (0, 0, 1), density * 2))
    for corner, su, normal in (((x0, y0, 0), (x1 - x0, 0, 0), (0, -1, 0)), ((x0, y1, 0), (x1 - x0, 0, 0), (0, 1, 0)),
                               ((x0, y0, 0), (0, y1 - y0, 0), (-1, 0, 0)), ((x1, y0, 0), (0, y1 - y0, 0), (1, 0, 0))):
        parts.append(_patch(rng, corner, su, (0, 0, z1), normal, density * 2))
    x = np.concatenate([p[0] for p in parts])
    n = np.concatenate([p[1] for p in parts])
    # a colour per surface, shaded +-0.03; the board on the x = 0 wall bluish white against the wall's plaster
    shade = rng.uniform(0.35, 0.85, (len(parts), 3))
    shade[2] = PLASTER
    colors = np.concatenate([np.broadcast_to(c, (len(p[0]), 3)) for c, p in zip(shade, parts)])
    on_board = (np.abs(x[:, 0]) < 1e-9) & (x[:, 1] >= BOARD[0]) & (x[:, 1] <= BOARD[1]) \
        & (x[:, 2] >= BOARD[2]) & (x[:, 2] <= BOARD[3])
    colors = np.where(on_board[:, None], BOARD_RGB, colors) + rng.uniform(-0.03, 0.03, (len(x), 3))
    x = x + n * rng.normal(0.0, OFFSET_NOISE_M, (len(x), 1))
    tilt = rng.normal(0.0, np.radians(TILT_NOISE_DEG) / np.sqrt(2), (len(x), 3))
    n = n + np.cross(tilt, n)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    outliers = int(0.02 * len(x))
    x = np.concatenate([x, rng.random((outliers, 3)) * np.array(ROOM) * 1.2 - 0.1 * np.array(ROOM)])
    n = np.concatenate([n, _unit(rng.normal(size=(outliers, 3)))])
    colors = np.concatenate([colors, rng.random((outliers, 3))]).clip(0, 1)
    c, s = np.cos(np.radians(tilt_deg)), np.sin(np.radians(tilt_deg))
    rot = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    x, n = x @ rot.T, n @ rot.T
    g = len(x)
    return {"gaussians/means": x, "gaussians/normals": n, "gaussians/log_scales": np.log(np.full((g, 3), 0.03)),
            "gaussians/rotations": np.tile([1.0, 0, 0, 0], (g, 1)), "gaussians/opacities": np.ones(g),
            "gaussians/colors": colors}, rot


def _unit(v):
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _write(path, fields):
    from rfir_core.artifacts import write_artifact

    write_artifact(path, "scene", fields)
    return path


@pytest.fixture(scope="module")
def room_result(tmp_path_factory):
    from rfir_core.artifacts import read_artifact
    from rfir_stages.geom.structure import run

    tmp = tmp_path_factory.mktemp("structure")
    fields, _ = sampled_room(np.random.default_rng(3))
    scene = _write(tmp / "room.h5", fields)
    result = run(scene, tmp / "planes.h5", {}, known_distance="floor:ceiling=2.8")
    return result, read_artifact(tmp / "planes.h5", "scene"), fields


def _true_planes():
    """name-free list of (inward normal [3], offset [m], size along the wall and up [m]) of the true shell."""
    lx, ly, lz = ROOM
    return {"floor": ((0, 0, 1), 0.0, None), "ceiling": ((0, 0, -1), -lz, None),
            "x0": ((1, 0, 0), 0.0, (ly, lz)), "x6": ((-1, 0, 0), -lx, (ly, lz)),
            "y0": ((0, 1, 0), 0.0, (lx, lz)), "y4": ((0, -1, 0), -ly, (lx, lz))}


def test_shell_matches_the_true_planes(room_result):
    result, _, _ = room_result
    found = {s.name: s for s in result.surfaces}
    assert {"floor", "ceiling"} <= set(found) and sum(s.kind == "wall" for s in result.surfaces) == 4
    truth = _true_planes()
    walls = [s for s in result.surfaces if s.kind == "wall"]
    for key, (normal, offset, size) in truth.items():
        if key in found:
            s = found[key]
        else:       # the wall whose normal is closest to this one's
            s = max(walls, key=lambda w: w.normal @ np.asarray(normal, float))
        angle = np.degrees(np.arccos(min(1.0, s.normal @ np.asarray(normal, float))))
        assert angle < 1.0, (key, angle)
        assert abs(s.offset - offset) < 0.02, (key, s.offset, offset)
        if size is not None:
            assert abs(s.size_m[0] - size[0]) <= 0.1 and abs(s.size_m[1] - size[1]) <= 0.1, (key, s.size_m, size)
    lx, ly, _ = ROOM
    for flat in (found["floor"], found["ceiling"]):       # the walls' outline, the unseen ceiling patch filled
        assert abs(flat.occupied.sum() * flat.cell_m ** 2 - lx * ly) < 0.05 * lx * ly
    assert not found["ceiling"].inferred


def test_door_is_an_opening_and_the_frame_is_level(room_result):
    result, _, _ = room_result
    walls = [s for s in result.surfaces if s.kind == "wall"]
    door_wall = max(walls, key=lambda w: -w.normal[1])
    door_m2 = (DOOR[1] - DOOR[0]) * (DOOR[3] - DOOR[2])
    assert abs(door_wall.openings_m2 - door_m2) < 0.3 * door_m2
    for w in walls:
        if w is not door_wall:
            assert w.openings_m2 < 0.1
    assert all(s.tilt_deg < 1.0 for s in result.surfaces) and not result.warnings
    _, _, known, measured = result.scale
    assert abs(measured - known) < 0.02


def test_artifact_has_labelled_planes_objects_and_free(room_result):
    result, art, fields = room_result
    names = [str(n) for n in art.attrs["label_names"]]
    labels = art.data["gaussians/labels"]
    x, n = art.data["gaussians/means"], art.data["gaussians/normals"]
    floor = labels == names.index("floor")
    assert np.allclose(x[floor, 2], 0.0, atol=0.02) and np.allclose(np.abs(n[floor, 2]), 1.0)
    assert result.num_objects >= 1 and any(name.startswith("object_") for name in names)
    # the table top: a plane of the object, projected onto it at 0.75 m
    obj = labels >= names.index("floor") + 6
    near_top = obj & (x[:, 2] > 0.5) & (np.abs(n[:, 2]) > 0.7)
    signed = n * np.sign(n[:, 2:3])
    rows, counts = np.unique(signed[near_top].round(12), axis=0, return_counts=True)
    plane_normal = rows[np.argmax(counts)]
    projected = near_top & (np.abs(signed - plane_normal).max(1) < 1e-12)    # noisy normals never coincide
    assert projected.sum() > 0.9 * near_top.sum() > 50
    assert np.degrees(np.arccos(plane_normal[2])) < 1.0
    offsets = x[projected] @ plane_normal
    assert np.ptp(offsets) < 1e-9 and abs(offsets[0] - TABLE[1][2]) < 0.02
    # outliers are free (label -1), and every input Gaussian is accounted for
    assert result.num_free == (labels == -1).sum() > 0
    assert result.num_on_shell + result.num_in_objects + result.num_free == len(fields["gaussians/means"])


def test_board_is_an_inset_of_its_wall(room_result):
    result, art, _ = room_result
    insets = [s for s in result.surfaces if s.kind == "inset"]
    assert [s.name for s in insets] == ["inset_a_00"]
    board = insets[0]
    # its host: the x = 0 wall, whose plane and grid it shares
    wall = next(s for s in result.surfaces if s.kind == "wall" and s.normal[0] > 0.99)
    assert board.occupied.shape == wall.occupied.shape and np.allclose(board.origin, wall.origin)
    board_m2 = (BOARD[1] - BOARD[0]) * (BOARD[3] - BOARD[2])
    area = board.occupied.sum() * board.cell_m ** 2
    assert abs(area - board_m2) < 0.15 * board_m2
    # its size is its own (2 x 1 m along the wall and up), not its host wall's
    assert sorted(board.size_m) == pytest.approx(sorted((BOARD[1] - BOARD[0], BOARD[3] - BOARD[2])), abs=0.15)
    assert not (board.occupied & wall.occupied).any()          # cut out of the wall: no surface twice
    names = [str(n) for n in art.attrs["label_names"]]
    x = art.data["gaussians/means"][art.data["gaussians/labels"] == names.index(board.name)]
    assert np.allclose(x[:, 0], 0.0, atol=0.02)
    assert x[:, 1].min() > BOARD[0] - 0.1 and x[:, 1].max() < BOARD[1] + 0.1
    assert x[:, 2].min() > BOARD[2] - 0.1 and x[:, 2].max() < BOARD[3] + 0.1


def test_shell_gaussians_projected_without_tiling(tmp_path):
    from rfir_core.artifacts import read_artifact
    from rfir_stages.geom.structure import run

    fields, _ = sampled_room(np.random.default_rng(4), density=100.0)
    result = run(_write(tmp_path / "room.h5", fields), tmp_path / "planes.h5", {"tile_shell": False})
    art = read_artifact(tmp_path / "planes.h5", "scene")
    names = [str(n) for n in art.attrs["label_names"]]
    labels = art.data["gaussians/labels"]
    assert len(labels) == len(fields["gaussians/means"])            # the input's Gaussians, none added
    assert ((labels >= 0) & (labels < names.index("object_00"))).sum() == result.num_on_shell
    x, n = art.data["gaussians/means"], art.data["gaussians/normals"]
    far_wall = next(s for s in result.surfaces if s.kind == "wall" and s.normal[0] < -0.99)
    floor = next(s for s in result.surfaces if s.name == "floor")
    for surface, value in ((floor, 0.0), (far_wall, -ROOM[0])):     # offsets along the inward normals
        on = labels == names.index(surface.name)
        offsets = x[on] @ surface.normal
        assert on.sum() > 100 and np.allclose(offsets, value, atol=0.02) and np.ptp(offsets) < 1e-9
        assert np.allclose(np.abs(n[on] @ surface.normal), 1.0, atol=1e-12)


def test_free_left_out_and_objects_as_planes(tmp_path):
    from rfir_core.artifacts import read_artifact
    from rfir_stages.geom.structure import run

    fields, _ = sampled_room(np.random.default_rng(6), density=100.0)
    result = run(_write(tmp_path / "room.h5", fields), tmp_path / "planes.h5",
                 {"keep_free": False, "object_planes_only": True})
    art = read_artifact(tmp_path / "planes.h5", "scene")
    names = [str(n) for n in art.attrs["label_names"]]
    labels, n = art.data["gaussians/labels"], art.data["gaussians/normals"]
    assert result.num_free > 0 and (labels >= 0).all()
    obj = labels >= names.index("object_00")
    # the table's Gaussians left are those on its planes: its top and sides, levelled and plumbed
    assert obj.sum() > 0.8 * (result.num_in_objects * 0.5)
    up = np.abs(n[obj, 2])
    assert ((np.abs(up - 1.0) < 1e-12) | (up < 1e-12)).all()


def test_tilted_frame_is_reported(tmp_path):
    from rfir_stages.geom.structure import run

    fields, _ = sampled_room(np.random.default_rng(5), density=100.0, tilt_deg=2.0)
    scene = _write(tmp_path / "room.h5", fields)
    result = run(scene, tmp_path / "planes.h5", {})
    floor = next(s for s in result.surfaces if s.name == "floor")
    assert abs(floor.tilt_deg - 2.0) < 0.3
    assert any("floor" in w and "horizontal" in w for w in result.warnings)


def test_refusals(tmp_path):
    from rfir_stages.geom.structure import run

    rng = np.random.default_rng(0)
    few, _ = sampled_room(rng, density=1.0)
    with pytest.raises(InputFileError, match="too few"):
        run(_write(tmp_path / "few.h5", few), tmp_path / "out.h5", {})
    pts, normals = _patch(rng, (0, 0, 0), (5, 0, 0), (0, 0, 3), (0, 1, 0), 200)   # one wall: no room
    g = len(pts)
    wall = {"gaussians/means": pts, "gaussians/normals": normals, "gaussians/log_scales": np.log(np.full((g, 3), 0.03)),
            "gaussians/rotations": np.tile([1.0, 0, 0, 0], (g, 1)), "gaussians/opacities": np.ones(g)}
    with pytest.raises(StageError, match="no floor"):
        run(_write(tmp_path / "wall.h5", wall), tmp_path / "out.h5", {})


def test_cli_one_line_error(tmp_path):
    from typer.testing import CliRunner

    from rfir_cli.main import app

    bad = tmp_path / "notes.h5"
    bad.write_text("not hdf5")
    r = CliRunner().invoke(app, ["structure", str(bad), "-o", str(tmp_path / "out.h5")])
    assert r.exit_code == 2
    assert len(r.output.strip().splitlines()) == 1 and "notes.h5" in r.output
    r = CliRunner().invoke(app, ["structure", str(bad), "-o", str(tmp_path / "o.h5"), "--known-distance", "floor=3"])
    assert r.exit_code in (2, 4)
