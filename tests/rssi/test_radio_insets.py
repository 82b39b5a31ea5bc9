"""Radio insets (rfir_stages.model.radio_insets): first-order reflection points against the mirror law, the search
for a part of a wall whose reflections carry larger residuals, and moved patches' path lengths against the
image method's exact lengths."""
from __future__ import annotations

from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import torch

from rfir_stages.model import radio_insets as ri
from rfir_stages.rf_fit.radio_inset_stage import _labelled


def test_reflection_point_obeys_the_mirror_law():
    tx, rx = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, 1.0]]), np.array([[3.0, 1.0, 2.0], [3.0, 1.0, -2.0]])
    hit, valid, w = ri.reflection_points(tx, rx, np.array([0.0, 0.0, 1.0]), np.zeros(3))
    assert valid.tolist() == [True, False]                 # the second link's ends lie on both sides of the plane
    np.testing.assert_allclose(hit[0], [5.0 / 3.0, 1.0, 0.0], atol=1e-12)
    a, b = tx[0] - hit[0], rx[0] - hit[0]                 # equal angles to the normal on both legs
    np.testing.assert_allclose(a[2] / np.linalg.norm(a), b[2] / np.linalg.norm(b), atol=1e-12)
    np.testing.assert_allclose(w[0], np.sqrt(5.0) / np.sqrt(13.0), atol=1e-12)


def _box_room(size=(8.0, 6.0, 3.0), spacing=0.25):
    """A stand-in PatchSet of a box room's four walls, floor and ceiling (normals into the room) and their surfels'
    centres on a grid."""
    lx, ly, lz = size
    planes = [((1, 0, 0), (0, ly / 2, lz / 2)), ((-1, 0, 0), (lx, ly / 2, lz / 2)), ((0, 1, 0), (lx / 2, 0, lz / 2)),
              ((0, -1, 0), (lx / 2, ly, lz / 2)), ((0, 0, 1), (lx / 2, ly / 2, 0)), ((0, 0, -1), (lx / 2, ly / 2, lz))]
    normal, point, u, v, area, means, owner = [], [], [], [], [], [], []
    for p, (n, o) in enumerate(planes):
        n, o = np.array(n, float), np.array(o, float)
        a = np.cross(n, [0, 0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0, 0])
        a /= np.linalg.norm(a)
        b = np.cross(n, a)
        ext_a = np.abs(a) @ np.array(size) / 2
        ext_b = np.abs(b) @ np.array(size) / 2
        ga, gb = np.meshgrid(np.arange(-ext_a + spacing / 2, ext_a, spacing), np.arange(-ext_b + spacing / 2, ext_b, spacing))
        pts = o + ga.reshape(-1, 1) * a + gb.reshape(-1, 1) * b
        normal.append(n), point.append(o), u.append(a), v.append(b), area.append(4 * ext_a * ext_b)
        means.append(pts), owner.append(np.full(len(pts), p))
    patches = SimpleNamespace(normal=np.array(normal), point=np.array(point), u=np.array(u), v=np.array(v),
                              area=np.array(area), surfel_patch=np.concatenate(owner))
    return patches, np.concatenate(means)


def _links(num, rng, size=(8.0, 6.0, 3.0)):
    lo, hi = np.array([0.5, 0.5, 0.8]), np.array([size[0] - 0.5, size[1] - 0.5, 2.4])
    return rng.uniform(lo, hi, (num, 3)), rng.uniform(lo, hi, (num, 3))


def _board_residuals(tx, rx, rng, board: bool):
    """|residual| ~ 1.2 dB everywhere, 2.5 times that on links reflecting off a 3 x 1.2 m board on the x = 0 wall
    (y 2-5 m, z 0.9-2.1 m) when `board`."""
    r = rng.normal(0.0, 1.5, len(tx))
    if board:
        hit, valid, _ = ri.reflection_points(tx, rx, np.array([1.0, 0.0, 0.0]), np.zeros(3))
        on = valid & (hit[:, 1] > 2.0) & (hit[:, 1] < 5.0) & (hit[:, 2] > 0.9) & (hit[:, 2] < 2.1)
        r[on] *= 2.5
    return r


def test_candidate_found_where_a_board_raises_the_residuals_and_nowhere_without_it():
    rng = np.random.default_rng(3)
    patches, means = _box_room()
    tx, rx = _links(12000, rng)
    found = ri.find_candidates(tx, rx, _board_residuals(tx, rx, rng, True), patches, means)
    assert len(found) >= 1
    c = found[0]
    assert c.patch == 0 and c.area_m2() > 1.5
    np.testing.assert_allclose(c.toward, [1.0, 0.0, 0.0])
    # the rectangle in world coordinates: y from u, z from v about the wall's centre (0, 3, 1.5)
    corners = patches.point[0] + np.array([[c.rect[0], c.rect[2]], [c.rect[1], c.rect[3]]]) @ \
        np.stack([patches.u[0], patches.v[0]])
    y, z = np.sort(corners[:, 1]), np.sort(corners[:, 2])
    # each edge placed at the step across it, within 0.25 m (the cells alone put it within 0.5 m)
    assert abs(y[0] - 2.0) <= 0.25 and abs(y[1] - 5.0) <= 0.25, y
    assert abs(z[0] - 0.9) <= 0.25 and abs(z[1] - 2.1) <= 0.25, z
    picked = ri.inset_surfels(c, patches, means, np.tile(patches.normal[0], (len(means), 1)))
    assert len(picked) > 0 and np.all(patches.surfel_patch[picked] == 0)
    rng = np.random.default_rng(4)
    tx, rx = _links(12000, rng)
    assert ri.find_candidates(tx, rx, _board_residuals(tx, rx, rng, False), patches, means) == []


@dataclass
class _Paths:
    length_m: torch.Tensor
    kind: torch.Tensor
    patch: torch.Tensor
    cos: torch.Tensor


def _mirror(p, axis, level):
    q = p.copy()
    q[..., axis] = 2 * level - q[..., axis]
    return q


def test_moved_patch_lengths_match_the_image_method():
    """A floor (patch 0, z = 0) and a ceiling (patch 1, z = 3): paths off the floor once, and floor then ceiling;
    the floor moved 2 cm up. The first-order length change equals the exact one to within d^2 / L."""
    rng = np.random.default_rng(0)
    tx, rx = rng.uniform([0, 0, 0.5], [6, 6, 2.5], (50, 3)), rng.uniform([0, 0, 0.5], [6, 6, 2.5], (50, 3))
    d = 0.02

    def once(floor):
        image = _mirror(tx, 2, floor)
        vec = rx - image
        return np.linalg.norm(vec, axis=1), np.abs(vec[:, 2]) / np.linalg.norm(vec, axis=1)

    def twice(floor):       # tx -> floor -> ceiling -> rx: tx mirrored in the floor, then in the ceiling
        image = _mirror(_mirror(tx, 2, floor), 2, 3.0)
        vec = rx - image
        return np.linalg.norm(vec, axis=1), np.abs(vec[:, 2]) / np.linalg.norm(vec, axis=1)

    l1, c1 = once(0.0)
    l2, c2 = twice(0.0)
    paths = _Paths(torch.as_tensor(np.concatenate([l1, l2])),
                   torch.as_tensor(np.concatenate([np.tile([1, 0], (50, 1)), np.tile([1, 1], (50, 1))])),
                   torch.as_tensor(np.concatenate([np.tile([0, -1], (50, 1)), np.tile([0, 1], (50, 1))])),
                   torch.as_tensor(np.concatenate([np.stack([c1, np.zeros(50)], 1), np.stack([c2, c2], 1)])))
    moved = ri.shift_lengths(paths, np.array([d, 0.0])).length_m.numpy()
    exact = np.concatenate([once(d)[0], twice(d)[0]])
    assert np.abs(exact - np.concatenate([l1, l2])).max() > 0.02          # the move matters at 12.5 cm
    np.testing.assert_allclose(moved, exact, atol=2 * d ** 2)


def test_a_later_rounds_insets_take_the_next_letters():
    # one patch, the x = 0 plane; a candidate over y 1..2, z 1..2; rf-fit's materials already hold an earlier radio_a
    patches = SimpleNamespace(point=np.zeros((1, 3)), normal=np.array([[1.0, 0.0, 0.0]]), u=np.array([[0.0, 1.0, 0.0]]),
                              v=np.array([[0.0, 0.0, 1.0]]))
    room = SimpleNamespace(patches=patches, material_of_patch=np.array([0]))
    means = np.array([[0.0, 1.5, 1.5], [0.0, 3.0, 1.5], [0.01, 1.2, 1.8]])
    normals = np.tile([1.0, 0.0, 0.0], (3, 1))
    cand = ri.InsetCandidate(0, np.array([1.0, 2.0, 1.0, 2.0]), 1.0, 4, np.array([1.0, 0.0, 0.0]))
    kept, labels, mat, lnames, mnames, source = _labelled([cand], np.array([0, 0, 1]), ["wall_00", "radio_a_00"],
                                                          np.array([0, 0, 1]), ["wall", "radio_a"], room, means, normals)
    assert kept == [cand] and lnames[-1] == "radio_b_00" and mnames[-1] == "radio_b" and source == [0]
    assert labels.tolist() == [2, 0, 2] and mat.tolist() == [2, 0, 2]
    # a second candidate over the same surfels, and one over none, get no label or material: every material kept has
    # surfels (the room's links count their materials from them)
    empty = ri.InsetCandidate(0, np.array([4.0, 5.0, 1.0, 2.0]), 1.0, 4, np.array([1.0, 0.0, 0.0]))
    kept, labels, mat, lnames, mnames, _ = _labelled([cand, cand, empty], np.array([0, 0, 0]), ["wall_00"],
                                                     np.array([0, 0, 0]), ["wall"], room, means, normals)
    assert kept == [cand] and mnames == ["wall", "radio_a"] and mat.tolist() == [1, 0, 1]
