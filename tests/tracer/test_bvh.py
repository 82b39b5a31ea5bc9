"""BVH: hit sets equal brute force; refit and rebuild after the Gaussians move."""
import pytest
import torch
from tracer_helpers import assert_results_close, make_scene, random_rays, random_scene, scene_args

import rfir_tracer as rt
from rfir_tracer.reference import trace_reference


def _hit_set(hits):
    rays = hits.ray_ids().tolist()
    return set(zip(rays, hits.gaussian_ids.tolist()))


@pytest.mark.parametrize("leaf_size", [1, 4, 16])
def test_hit_sets_equal_brute_force(leaf_size):
    """All hits (t_stop = 0, so nothing is cut off) equal the every-ray-every-Gaussian set."""
    s = random_scene(400, seed=20, spread=1.5, scale=-2.0)
    o, d = random_rays(500, seed=21, jitter=1.5)
    scene = make_scene(s, leaf_size=leaf_size)
    out = rt.trace(scene, o, d, t_stop=0.0, return_hits=True)
    ref = trace_reference(*scene_args(s), o, d, t_stop=0.0)
    assert out.hits.num_hits > 1000
    assert _hit_set(out.hits) == _hit_set(ref.hits)


def test_float32_bvh_equals_single_leaf_brute_force():
    """In float32 the BVH must not lose hits: compare with a one-leaf tree (every Gaussian tested)."""
    s = {k: v.float() for k, v in random_scene(500, seed=22, spread=1.5, scale=-2.2, flat=True).items()}
    o, d = random_rays(800, seed=23, dtype=torch.float32, jitter=1.5)
    tree = rt.trace(make_scene(s), o, d, t_stop=0.0, return_hits=True)
    brute = rt.trace(make_scene(s, leaf_size=10_000), o, d, t_stop=0.0, return_hits=True)
    assert tree.hits.num_hits > 500
    assert _hit_set(tree.hits) == _hit_set(brute.hits)
    assert torch.equal(tree.hits.gaussian_ids, brute.hits.gaussian_ids)


def test_refit_after_in_place_move_and_rebuild():
    s = random_scene(200, seed=24)
    o, d = random_rays(300, seed=25)
    scene = make_scene(s)
    rt.trace(scene, o, d)
    with torch.no_grad():  # an optimiser-like in-place step: the scene notices and refits
        s["means"].add_(torch.randn_like(s["means"]) * 0.3)
        s["log_scales"].add_(0.2)
    moved = rt.trace(scene, o, d, features=s["features"])
    assert scene.refits_since_build == 1
    ref = trace_reference(*scene_args(s), o, d, features=s["features"], normals=s["normals"])
    assert_results_close(moved, ref)
    rebuilt = rt.trace(scene.rebuild(), o, d, features=s["features"])
    assert_results_close(rebuilt, ref)


def test_update_swaps_tensors():
    s = random_scene(150, seed=26)
    t = random_scene(150, seed=27)
    o, d = random_rays(200, seed=28)
    scene = make_scene(s)
    scene.update(means=t["means"], log_scales=t["log_scales"], rotations=t["rotations"],
                 opacities=t["opacities"], normals=t["normals"])
    out = rt.trace(scene, o, d, features=t["features"])
    ref = trace_reference(*scene_args(t), o, d, features=t["features"], normals=t["normals"])
    assert_results_close(out, ref)
    scene.update(means=t["means"][:100], log_scales=t["log_scales"][:100], rotations=t["rotations"][:100],
                 opacities=t["opacities"][:100], normals=t["normals"][:100], rebuild=True)
    assert scene.num_gaussians == 100 and scene.prim_order.shape == (100,)


def test_build_is_a_valid_tree():
    s = random_scene(1000, seed=29, spread=3.0)
    scene = make_scene(s)
    nodes = scene.nodes
    count = nodes[:, 7]
    leaves = count > 0
    assert int(count[leaves].sum()) == 1000  # every Gaussian in exactly one leaf
    assert sorted(scene.prim_order.tolist()) == list(range(1000))
    bounds = nodes[:, [0, 1, 2, 4, 5, 6]].contiguous().view(torch.float32)
    inner = torch.nonzero(~leaves).flatten()
    for child in (0, 1):
        c = nodes[inner, 3] + child
        assert bool((bounds[c, :3] >= bounds[inner, :3]).all() and (bounds[c, 3:] <= bounds[inner, 3:]).all())
