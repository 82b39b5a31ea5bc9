"""Forward pass of the native tracer against the brute-force float64 reference."""
import math

import pytest
import torch
from tracer_helpers import assert_results_close, make_scene, random_rays, random_scene, scene_args

import rfir_tracer as rt
from rfir_tracer.reference import trace_reference


def _ref(s, o, d, **kw):
    return trace_reference(*scene_args(s), o, d, features=s["features"], normals=s["normals"], **kw)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_forward_matches_reference(seed):
    s = random_scene(150, seed=seed)
    o, d = random_rays(400, seed=seed + 10)
    out = rt.trace(make_scene(s), o, d, features=s["features"], return_hits=True)
    ref = _ref(s, o, d)
    assert_results_close(out, ref, rtol=1e-5, atol=1e-10)
    assert int(out.hit_count.sum()) > 400  # the scene is actually hit
    assert torch.equal(out.hits.offsets, ref.hits.offsets)
    assert torch.equal(out.hits.gaussian_ids, ref.hits.gaussian_ids)
    torch.testing.assert_close(out.hits.t, ref.hits.t, rtol=1e-10, atol=1e-12)
    torch.testing.assert_close(out.hits.response, ref.hits.response, rtol=1e-10, atol=1e-12)


def test_float32_close_to_reference():
    s64 = random_scene(150, seed=4)
    s32 = {k: v.float() for k, v in s64.items()}
    o, d = random_rays(400, seed=5)
    out = rt.trace(make_scene(s32), o.float(), d.float(), features=s32["features"], return_hits=True)
    ref = _ref(s64, o, d)
    assert out.features.dtype == torch.float32
    same = out.hit_count.long() == ref.hit_count.long()
    assert same.float().mean() > 0.98  # threshold decisions may flip in float32, rarely
    for f in ("features", "depth", "transmittance", "normal"):
        x, y = getattr(out, f)[same].double(), getattr(ref, f)[same]
        torch.testing.assert_close(x, y, rtol=1e-3, atol=2e-4, msg=f)


def test_per_ray_limits_and_params():
    s = random_scene(150, seed=6)
    o, d = random_rays(300, seed=7)
    g = torch.Generator().manual_seed(0)
    t_min = torch.rand(300, generator=g, dtype=torch.float64) * 3.0
    t_max = t_min + torch.rand(300, generator=g, dtype=torch.float64) * 3.0
    scene = make_scene(s)
    kw = dict(t_min=t_min, t_max=t_max, alpha_min=1e-3, t_stop=0.05)
    out = rt.trace(scene, o, d, features=s["features"], **kw)
    assert scene.bvh_alpha_min == 1e-3  # widened for the smaller alpha_min
    assert_results_close(out, _ref(s, o, d, **kw))


def test_many_hits_per_ray_and_ties():
    """More hits than the k-buffer holds (several passes) and exact ties in t*."""
    n = 300
    means = torch.zeros(n, 3, dtype=torch.float64)
    means[:, 2] = torch.linspace(-2, 2, n // 2, dtype=torch.float64).repeat(2)  # pairs share t*
    s = dict(means=means, log_scales=torch.full((n, 3), -1.0, dtype=torch.float64),
             rotations=torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64).repeat(n, 1),
             opacities=torch.full((n,), 0.02, dtype=torch.float64),
             normals=torch.nn.functional.normalize(torch.randn(n, 3, dtype=torch.float64), dim=1),
             features=torch.rand(n, 2, dtype=torch.float64))
    o = torch.tensor([[0.01, -0.02, -5.0], [0.0, 0.0, -5.0]], dtype=torch.float64)
    d = torch.tensor([[0.0, 0.0, 1.0], [0.01, 0.0, 1.0]], dtype=torch.float64)
    out = rt.trace(make_scene(s), o, d, features=s["features"], return_hits=True, t_stop=0.0)
    ref = _ref(s, o, d, t_stop=0.0)
    assert int(out.hit_count.min()) == n
    assert_results_close(out, ref)
    assert torch.equal(out.hits.gaussian_ids, ref.hits.gaussian_ids)


def test_batch_shapes_and_broadcast_origin():
    s = random_scene(80, seed=8)
    o, d = random_rays(12, seed=9)
    out = rt.trace(make_scene(s), o[0], d.reshape(3, 4, 3), features=s["features"], t_max=10.0)
    assert out.features.shape == (3, 4, 4) and out.normal.shape == (3, 4, 3)
    assert out.depth.shape == (3, 4) and out.hit_count.dtype == torch.int32
    flat = rt.trace(make_scene(s), o[:1].expand(12, 3), d, features=s["features"], t_max=10.0)
    torch.testing.assert_close(out.depth.reshape(-1), flat.depth)


def test_exclude_ids():
    s = random_scene(100, seed=10)
    o, d = random_rays(50, seed=11)
    ex = torch.randint(0, 100, (50,))
    out = rt.trace(make_scene(s), o, d, features=s["features"], exclude=ex, return_hits=True)
    assert_results_close(out, _ref(s, o, d, exclude=ex))
    rays = out.hits.ray_ids()
    assert not bool((out.hits.gaussian_ids.long() == ex[rays]).any())


def test_opacity_override_and_no_normals():
    s = random_scene(100, seed=12)
    o, d = random_rays(60, seed=13)
    scene = rt.GaussianScene(s["means"], s["log_scales"], s["rotations"])  # opacities 1, no normals
    rf = torch.rand(100, dtype=torch.float64)
    out = rt.trace(scene, o, d, opacities=rf)
    ref = trace_reference(s["means"], s["log_scales"], s["rotations"], rf, o, d)
    torch.testing.assert_close(out.transmittance, ref.transmittance, rtol=1e-5, atol=1e-12)
    assert out.features.shape == (60, 0) and float(out.normal.abs().max()) == 0.0
    assert math.isclose(float(out.opacity[0]), 1 - float(out.transmittance[0]))
