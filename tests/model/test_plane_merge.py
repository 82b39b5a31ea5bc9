"""Planar patches of scattered Gaussians (rfir_stages.model.plane_merge via second_order.planar_patches).

- the scatter of Gaussians about their local planes: recovered from offsets along the normals, 0 for exact surfels;
- a wall of Gaussians scattered by 1 cm along its normal, their normals tilted by 3 degrees: one patch on its plane;
- the two faces of a scattered 8 cm slab: joining neighbours within 1 cm joins them (one stray pair does), plane
  fitting keeps them two patches; exact surfels of a 2 cm slab are joined as before, the faces apart;
- a scattered cylinder (radius 2 m): no patch bends further from its own plane than the tolerance.
"""
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from rfir_stages.model.plane_merge import merge_coplanar, offset_scatter_m
from rfir_stages.model.second_order import PARALLEL_COS, planar_patches


def _geom(x, n):
    return SimpleNamespace(means=torch.as_tensor(x, dtype=torch.float64),
                           normals=torch.as_tensor(n / np.linalg.norm(n, axis=1, keepdims=True), dtype=torch.float64),
                           num=len(x))


def _wall(rng, size=(4.0, 3.0), step=0.1, sigma=0.01, tilt_deg=3.0, offset=0.0, normal_sign=1.0):
    """Gaussians on the plane z = offset over size [m] at step [m], moved along z by N(0, sigma), normals +-z
    tilted by N(0, tilt_deg) about random axes. Returns x, n [G, 3], areas [G]."""
    u, v = np.meshgrid(np.arange(0, size[0], step), np.arange(0, size[1], step), indexing="ij")
    g = u.size
    x = np.stack([u.ravel(), v.ravel(), offset + rng.normal(0, sigma, g)], 1)
    t = np.radians(tilt_deg) * rng.normal(size=(g, 2))
    n = normal_sign * np.stack([t[:, 0], t[:, 1], np.ones(g)], 1)
    return x, n, np.full(g, step * step)


def _patch_rms(patches, x, p):
    """RMS offset [m] of patch p's members from its plane."""
    m = patches.members[p]
    return float(np.sqrt(np.mean(((x[m] - patches.point[p]) @ patches.normal[p]) ** 2)))


def test_scatter_is_recovered_and_zero_on_exact_surfels():
    rng = np.random.default_rng(0)
    from scipy.spatial import cKDTree

    for sigma in (0.0, 0.005, 0.02):
        x, n, _ = _wall(rng, sigma=sigma, tilt_deg=0.0)
        pairs = cKDTree(x).query_pairs(0.25, output_type="ndarray")
        i, j = pairs[:, 0], pairs[:, 1]
        got = offset_scatter_m(x, i, j, np.ones(len(i), bool))
        if sigma == 0:
            assert got < 1e-9
        else:
            assert got == pytest.approx(sigma, rel=0.2)


def test_scattered_wall_is_one_patch():
    rng = np.random.default_rng(1)
    x, n, a = _wall(rng)
    merged = planar_patches(_geom(x, n), torch.as_tensor(a), min_patch_area_m2=0.0, coplanar_m=0.01,
                            merge_scatter_factor=2.0)
    assert merged.merge_tol_m == pytest.approx(0.02, rel=0.3)
    assert merged.area.max() > 0.97 * a.sum()
    big = int(np.argmax(merged.area))
    assert abs(merged.normal[big][2]) > 0.9999         # the mean of 1200 tilted normals
    assert _patch_rms(merged, x, big) < merged.merge_tol_m


def test_slab_faces_stay_apart_and_exact_surfels_do_not_merge():
    rng = np.random.default_rng(2)
    xa, na, aa = _wall(rng, size=(2.0, 1.0), offset=0.0, normal_sign=1.0)
    xb, nb, ab = _wall(rng, size=(2.0, 1.0), offset=0.08, normal_sign=-1.0)
    x, n, a = np.concatenate([xa, xb]), np.concatenate([na, nb]), np.concatenate([aa, ab])
    merged = planar_patches(_geom(x, n), torch.as_tensor(a), min_patch_area_m2=0.0, coplanar_m=0.01,
                            merge_scatter_factor=2.0)
    joined = planar_patches(_geom(x, n), torch.as_tensor(a), min_patch_area_m2=0.0, coplanar_m=0.01)
    assert joined.area.max() > aa.sum() + 0.5 * ab.sum()   # neighbour joining chains across the faces
    face = np.r_[np.zeros(len(xa), int), np.ones(len(xb), int)]
    for m in merged.members:
        assert len(np.unique(face[m])) == 1            # no patch holds both faces
    assert sorted(merged.area)[-2] > 0.95 * aa.sum()   # each face one patch
    # exact surfels of a 2 cm slab: no scatter, no merging, the faces apart
    xs, ns, as_ = _wall(rng, size=(2.0, 1.0), sigma=0.0, tilt_deg=0.0)
    xt, nt, at = _wall(rng, size=(2.0, 1.0), sigma=0.0, tilt_deg=0.0, offset=0.02, normal_sign=-1.0)
    exact = planar_patches(_geom(np.concatenate([xs, xt]), np.concatenate([ns, nt])),
                           torch.as_tensor(np.concatenate([as_, at])), min_patch_area_m2=0.0, coplanar_m=0.01,
                           merge_scatter_factor=2.0)
    assert exact.merge_tol_m == 0.0 and len(exact.area) == 2   # joined at coplanar_m, as without merging


def test_merged_patches_stay_within_their_tolerance_on_a_curved_surface():
    rng = np.random.default_rng(3)
    radius, sigma = 2.0, 0.01
    phi, h = np.meshgrid(np.arange(0, np.pi, 0.05), np.arange(0, 2.0, 0.1), indexing="ij")
    r = radius + rng.normal(0, sigma, phi.size)
    x = np.stack([r * np.cos(phi.ravel()), r * np.sin(phi.ravel()), h.ravel()], 1)
    n = np.stack([np.cos(phi.ravel()), np.sin(phi.ravel()), np.zeros(phi.size)], 1)
    a = np.full(phi.size, 0.1 * 0.1)
    merged = planar_patches(_geom(x, n), torch.as_tensor(a), min_patch_area_m2=0.0, coplanar_m=0.01,
                            merge_scatter_factor=2.0)
    assert merged.merge_tol_m > 0
    assert len(merged.area) >= 4                       # a half cylinder is not one plane
    for p in range(len(merged.area)):
        if len(merged.members[p]) > 1:
            assert _patch_rms(merged, x, p) <= merged.merge_tol_m * (1 + 1e-9)


def test_merge_needs_a_shared_neighbour_pair():
    x = np.array([[0.0, 0, 0], [0.1, 0, 0], [5.0, 0, 0], [5.1, 0, 0]])
    n = np.tile([0.0, 0, 1], (4, 1))
    comp = np.array([0, 0, 1, 1])
    # coplanar but never neighbours: left apart; one pair between them: merged
    assert list(merge_coplanar(comp, x, n, np.ones(4), np.array([0]), np.array([1]), PARALLEL_COS, 0.01)) == [0, 0, 1, 1]
    assert len(set(merge_coplanar(comp, x, n, np.ones(4), np.array([1]), np.array([2]), PARALLEL_COS, 0.01))) == 1


def test_rf_fit_says_how_patches_were_grouped():
    from rfir_stages.model.room import RoomSettings
    from rfir_stages.rf_fit.room_stage import patch_grouping

    rng = np.random.default_rng(4)
    x, n, a = _wall(rng, size=(2.0, 2.0), sigma=0.015)
    merged = planar_patches(_geom(x, n), torch.as_tensor(a), min_patch_area_m2=0.0, coplanar_m=0.01,
                            merge_scatter_factor=RoomSettings().merge_scatter_factor)
    words = patch_grouping(RoomSettings(), merged.merge_tol_m)
    import re

    m = re.fullmatch(r"planes fitted to an RMS offset of at most ([\d.]+) cm, 2 x the Gaussians' scatter of ([\d.]+) "
                     r"cm about their planes", words)
    assert m and float(m[2]) == pytest.approx(1.5, rel=0.15) and float(m[1]) == pytest.approx(2 * float(m[2]), abs=0.15)
    assert patch_grouping(RoomSettings(), 0.0) == "neighbours within 0.01 m of one plane joined"
    from rfir_stages.rf_fit.room_stage import diffuse_words

    assert "patches under 0.12 m^2 pooled" in diffuse_words(RoomSettings(), 10)
    assert "a cell per patch and voxel" in diffuse_words(RoomSettings(small_patch_share=0.0), 10)
