"""`rfir structure` on other rooms and other Gaussians: an L-shaped room (its inner corner kept), a room tiled by
`mesh-gaussians` (coarse wall surfels beside finely tiled furniture: votes by area), and the outline of a simple
polygon that is neither convex nor rectilinear (rfir_stages.geom.planes, room_shell)."""
from __future__ import annotations

import numpy as np
import pytest

HEIGHT = 2.8
# The L: [0, 6] x [0, 3] and [0, 3] x [3, 6] (metres), corners in order around the room; its area 27 m^2.
L_CORNERS = np.array([(0, 0), (6, 0), (6, 3), (3, 3), (3, 6), (0, 6)], float)
L_AREA_M2 = 27.0
DESKS_X = (0.6, 1.9, 3.2, 4.5)     # a row of desks along y = 1.0 .. 1.6, 1.2 m wide, 0.75 m high: coplanar fronts
DESK = (1.2, 0.6, 0.75)


def _quad(corner, side_u, side_v):
    """Vertices [4, 3] and faces [2, 3] of the rectangle corner + [0, 1] side_u + [0, 1] side_v."""
    c, u, v = (np.asarray(a, float) for a in (corner, side_u, side_v))
    return np.array([c, c + u, c + u + v, c + v]), np.array([[0, 1, 2], [0, 2, 3]])


def _walls_of(corners):
    """The rectangles (corner, side_u, side_v) of the walls of a room with the floor polygon corners [K, 2]."""
    out = []
    for a, b in zip(corners, np.roll(corners, -1, axis=0)):
        out.append(((a[0], a[1], 0.0), (b[0] - a[0], b[1] - a[1], 0.0), (0.0, 0.0, HEIGHT)))
    return out


def _l_rectangles():
    """The L room's rectangles: floor and ceiling as two rectangles each, then its six walls."""
    flats = []
    for z in (0.0, HEIGHT):
        flats += [((0, 0, z), (6, 0, 0), (0, 3, 0)), ((0, 3, z), (3, 0, 0), (0, 3, 0))]
    return flats + _walls_of(L_CORNERS)


def _sampled(rng, rectangles, density, noise_m=0.02, tilt_deg=3.0, scale_m=0.03):
    """Photo-like Gaussian fields sampled on the rectangles: positions scattered noise_m along the normal, normals
    tilted by some degrees, all of one small scale."""
    xs, ns = [], []
    for corner, su, sv in rectangles:
        su, sv = np.asarray(su, float), np.asarray(sv, float)
        normal = np.cross(su, sv) / np.linalg.norm(np.cross(su, sv))
        k = int(density * np.linalg.norm(su) * np.linalg.norm(sv))
        a, b = rng.random((2, k))
        xs.append(np.asarray(corner, float) + np.outer(a, su) + np.outer(b, sv) + np.outer(rng.normal(0, noise_m, k), normal))
        tilt = rng.normal(0, np.radians(tilt_deg) / np.sqrt(2), (k, 3))
        n = normal + np.cross(tilt, normal)
        ns.append(n / np.linalg.norm(n, axis=1, keepdims=True))
    x, n = np.concatenate(xs), np.concatenate(ns)
    g = len(x)
    return {"gaussians/means": x, "gaussians/normals": n, "gaussians/log_scales": np.log(np.full((g, 3), scale_m)),
            "gaussians/rotations": np.tile([1.0, 0, 0, 0], (g, 1)), "gaussians/opacities": np.ones(g)}


def _tiled(rectangles, spacing_m):
    """Fields of mesh-gaussians' surfels on the rectangles (each a quad of two triangles) at spacing_m."""
    from rfir_stages.geom.from_mesh import gaussians_from_mesh

    verts, faces = [], []
    for corner, su, sv in rectangles:
        v, f = _quad(corner, su, sv)
        faces.append(f + 4 * len(verts))
        verts.append(v)
    fields = gaussians_from_mesh(np.concatenate(verts), np.concatenate(faces), spacing_m, rectangles=True)
    return {k: v for k, v in fields.items() if k != "gaussians/labels"}


def _desk_rectangles():
    w, d, h = DESK
    out = []
    for x0 in DESKS_X:
        y0 = 1.0
        out += [((x0, y0, h), (w, 0, 0), (0, d, 0)),                        # top
                ((x0, y0, 0), (w, 0, 0), (0, 0, h)), ((x0, y0 + d, 0), (w, 0, 0), (0, 0, h)),   # front, back
                ((x0, y0, 0), (0, d, 0), (0, 0, h)), ((x0 + w, y0, 0), (0, d, 0), (0, 0, h))]   # sides
    return out


def _joined(*parts):
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _write(path, fields):
    from rfir_core.artifacts import write_artifact

    write_artifact(path, "scene", fields)
    return path


def _cyclic_match(found, truth, tol_m):
    """Whether polygon found [K, 2] has the vertices of truth [K, 2] in the same cyclic order (either direction)."""
    if len(found) != len(truth):
        return False
    for seq in (found, found[::-1]):
        for shift in range(len(seq)):
            if np.abs(np.roll(seq, shift, axis=0) - truth).max() <= tol_m:
                return True
    return False


def _check_l_shell(result, offset_tol_m):
    """The six walls on the L's six lines, the floor and ceiling covering the L and not its missing square."""
    walls = [s for s in result.surfaces if s.kind == "wall"]
    assert len(walls) == 6, [s.name for s in walls]
    lines = {(0, 1): 0.0, (-1, 0): -6.0, (0, -1): -3.0, (-1, 0, "inner"): -3.0, (0, -1, "top"): -6.0, (1, 0): 0.0}
    found = sorted((tuple(np.round(w.normal[:2]).astype(int)), round(w.offset, 3)) for w in walls)
    truth = sorted(((k[0], k[1]), v) for k, v in lines.items())
    for (n_f, o_f), (n_t, o_t) in zip(found, truth):
        assert n_f == n_t and abs(o_f - o_t) < offset_tol_m, (found, truth)
    for w in walls:
        assert np.degrees(np.arcsin(min(1.0, abs(w.normal[2])))) < 1.0
    for flat in (s for s in result.surfaces if s.kind in ("floor", "ceiling")):
        area = flat.occupied.sum() * flat.cell_m ** 2
        assert abs(area - L_AREA_M2) < 0.03 * L_AREA_M2, (flat.name, area)
        cells = flat.origin[:2] + (np.argwhere(flat.occupied) + 0.5) * flat.cell_m
        assert not ((cells[:, 0] > 3.2) & (cells[:, 1] > 3.2)).any()          # the missing square stays out
        near_inner = (np.abs(cells[:, 0] - 2.95) < 0.06) & (np.abs(cells[:, 1] - 3.05) < 0.06)
        assert near_inner.any()                                               # the inner corner is not cut


def test_l_shaped_room_from_photo_gaussians(tmp_path):
    from rfir_stages.geom.structure import run

    fields = _sampled(np.random.default_rng(11), _l_rectangles(), density=120.0)
    result = run(_write(tmp_path / "l.h5", fields), tmp_path / "planes.h5", {"insets": False})
    _check_l_shell(result, offset_tol_m=0.02)


def test_l_shaped_room_from_mesh_surfels_beside_finely_tiled_desks(tmp_path):
    """Walls in surfels of up to 0.4 m (mesh-gaussians --preset room), desks in cells of 4 cm: the desks' coplanar
    fronts hold many more Gaussians than any wall, but far less area, and the walls are found exactly."""
    from rfir_stages.geom.structure import run

    fields = _joined(_tiled(_l_rectangles(), 0.8), _tiled(_desk_rectangles(), 0.08))
    result = run(_write(tmp_path / "l_mesh.h5", fields), tmp_path / "planes.h5", {"insets": False})
    _check_l_shell(result, offset_tol_m=1e-6)
    assert result.num_objects >= 1


def test_plane_votes_count_area_not_gaussians():
    """The first upright plane found is the largest wall by area; counting Gaussians instead (areas_m2=None), the
    row of desk fronts (more Gaussians, a tenth of the area) comes first: what the area votes are for."""
    from rfir_stages.geom.planes import find_planes, footprint_areas_m2

    walls = _tiled(_walls_of(np.array([(0, 0), (6, 0), (6, 4), (0, 4)], float)), 0.8)
    fields = _joined(walls, _tiled(_desk_rectangles(), 0.08))
    x, n = fields["gaussians/means"], fields["gaussians/normals"]
    n = n / np.linalg.norm(n, axis=1, keepdims=True)
    upright = np.abs(n[:, 2]) < 0.5
    x, n, log_scales = x[upright], n[upright], fields["gaussians/log_scales"][upright]
    areas = footprint_areas_m2(log_scales)
    kw = dict(distance_m=0.03, normal_deg=10.0, min_points=40, min_area_m2=2.0, piece_eps_m=0.2, max_planes=1)
    by_area = find_planes(x, n, areas_m2=areas, **kw)[0]
    by_count = find_planes(x, n, **kw)[0]
    assert abs(abs(by_area.normal[1]) - 1.0) < 1e-6 and abs(abs(by_area.offset) - 0.0) < 1e-6     # the y = 0 wall
    assert areas[by_area.members].sum() == pytest.approx(6.0 * HEIGHT, rel=1e-6)
    assert abs(abs(by_count.offset) - 1.0) < 0.05 or abs(abs(by_count.offset) - 1.6) < 0.05         # a desk face row


def test_footprint_area_and_pieces_of_mixed_sizes():
    """pi s1 s2 of the two largest scales is the area a surfel stands for (mesh-gaussians tiles a 2 x 3 m rectangle
    into surfels adding up to 6 m^2); coarse surfels and a patch of fine Gaussians on one plane are one piece,
    as the footprints touch, while centre distances alone (no radii) split the coarse surfels apart."""
    from rfir_stages.geom.planes import connected_pieces, footprint_areas_m2, votes_and_radii

    wall = _tiled([((0, 0, 0), (2, 0, 0), (0, 0, 3))], 0.8)
    areas = footprint_areas_m2(wall["gaussians/log_scales"])
    assert areas.sum() == pytest.approx(6.0, rel=1e-9)
    rng = np.random.default_rng(2)
    fine = np.column_stack([0.5 + 0.6 * rng.random(300), np.zeros(300), 1.0 + 0.6 * rng.random(300)])
    x = np.concatenate([wall["gaussians/means"], fine])
    all_areas = np.concatenate([areas, np.full(300, np.pi * 0.02 ** 2)])
    votes, radii = votes_and_radii(all_areas, len(x))
    piece = connected_pieces(x, 0.1, 40, radii=radii, weights=votes, min_weight=2.0)
    assert (piece == piece[0]).all() and piece[0] >= 0
    alone = connected_pieces(x, 0.1, 40)
    assert (alone[: len(areas)] == -1).any()


def test_weighted_quantile_matches_closed_forms():
    from rfir_stages.geom.planes import weighted_quantile

    values = np.array([3.0, 1.0, 2.0, 4.0])
    # equal weights: the 'hazen' percentiles, (k - 1/2) / n at the k-th smallest value
    assert weighted_quantile(values, np.ones(4), [0.125, 0.375, 0.625, 0.875]) == pytest.approx([1, 2, 3, 4])
    assert weighted_quantile(values, np.ones(4), 0.5) == pytest.approx(2.5)
    # a weight of 3 on the value 4: cumulative centres 0.5, 1.5, 2.5, 4.5 of 6; the median, at 3, is a quarter of
    # the way from the value 3 (at 2.5) to the value 4 (at 4.5)
    assert weighted_quantile(values, np.array([1, 1, 1, 3.0]), 0.5) == pytest.approx(3.25)


def _wall(name, a, b):
    """A wall Surface from xy end a to b with its extent set (u along a -> b, room on its left)."""
    from rfir_stages.geom.room_shell import UP, Surface

    a, b = np.asarray(a, float), np.asarray(b, float)
    u = np.append(b - a, 0.0) / np.linalg.norm(b - a)
    normal = np.cross(UP, u)
    origin = np.append(a, 0.0)
    cells = int(round(np.linalg.norm(b - a) / 0.1))
    s = Surface(name, "wall", normal, float(normal @ origin), np.zeros(0, np.int64), 0.0, origin=origin, u=u,
                v=UP.copy(), cell_m=float(np.linalg.norm(b - a)) / cells)      # cells that end exactly at b
    s.occupied = np.ones((cells, 28), bool)
    return s


@pytest.mark.parametrize("corners", [
    L_CORNERS,
    np.array([(0, 0), (5, 0), (6, 2.5), (3, 2), (2, 5), (0, 4)], float),      # neither convex nor rectilinear
])
def test_outline_follows_the_walls_around_the_room(corners):
    """The walls listed out of order, each reversed or not, with their corners: the outline is the polygon."""
    from rfir_stages.geom.room_shell import Corner, room_outline

    k = len(corners)
    order = [3, 0, 5, 1, 4, 2]
    flip = [False, True, False, False, True, True]
    walls, where = [], {}
    for slot, (i, f) in enumerate(zip(order, flip)):
        a, b = corners[i], corners[(i + 1) % k]
        walls.append(_wall(f"wall_{slot:02d}", *((b, a) if f else (a, b))))
        where[i] = (slot, f)
    corner_list = []
    for i in range(k):           # wall i's end b meets wall i+1's end a
        (s1, f1), (s2, f2) = where[i], where[(i + 1) % k]
        corner_list.append(Corner(s1, 0 if f1 else 1, s2, 1 if f2 else 0, corners[(i + 1) % k]))
    outline = room_outline(walls, corner_list)
    assert _cyclic_match(outline, corners, 1e-6), outline


def test_outline_across_a_missing_wall():
    """A box room whose fourth wall was not found: the outline closes straight across the gap."""
    from rfir_stages.geom.room_shell import Corner, room_outline

    box = np.array([(0, 0), (6, 0), (6, 4), (0, 4)], float)
    walls = [_wall("wall_00", box[0], box[1]), _wall("wall_01", box[1], box[2]), _wall("wall_02", box[2], box[3])]
    corners = [Corner(0, 1, 1, 0, box[1]), Corner(1, 1, 2, 0, box[2])]
    assert _cyclic_match(room_outline(walls, corners), box, 1e-6)


def test_small_floaters_behind_the_floor_and_an_inner_wall_do_not_unmake_them(tmp_path):
    """Photo Gaussians float a few cm behind real surfaces, smaller than the surface's own. A plane is a boundary
    when at most boundary_share of the footprint area within its extent lies behind it, not of the count: floaters
    8-12 cm under the floor and behind the L's inner walls, 12 % of those surfaces' Gaussians but a ninth of
    their size each, leave the floor at z = 0 and the inner corner's walls in place."""
    from rfir_stages.geom.structure import run

    rng = np.random.default_rng(12)
    room = _sampled(rng, _l_rectangles(), density=120.0)
    floor = ((0, 0, 0), (6, 0, 0), (0, 3, 0)), ((0, 3, 0), (3, 0, 0), (0, 3, 0))
    inner = ((6, 3, 0), (-3, 0, 0), (0, 0, HEIGHT)), ((3, 3, 0), (0, 3, 0), (0, 0, HEIGHT))
    floaters = []
    for rects, behind in ((floor, np.array([0, 0, -1.0])), (inner[:1], np.array([0, 1.0, 0])),
                          (inner[1:], np.array([1.0, 0, 0]))):
        layer = _sampled(rng, rects, density=120.0 * 0.12, scale_m=0.01)
        layer["gaussians/means"] = layer["gaussians/means"] + np.outer(rng.uniform(0.08, 0.12, len(
            layer["gaussians/means"])), behind)
        floaters.append(layer)
    result = run(_write(tmp_path / "f.h5", _joined(room, *floaters)), tmp_path / "planes.h5", {"insets": False})
    floor_found = next(s for s in result.surfaces if s.kind == "floor")
    assert abs(floor_found.offset) < 0.02, floor_found.offset
    _check_l_shell(result, offset_tol_m=0.03)
