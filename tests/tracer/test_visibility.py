"""transmittance_to_points: incident-field visibility (docs/physics.md section 4.1)."""
import pytest
import torch
from tracer_helpers import make_scene, random_scene, scene_args

import rfir_tracer as rt
from rfir_tracer.reference import transmittance_reference


def test_visibility_matches_reference():
    s = random_scene(300, seed=60, spread=1.5, scale=-2.0)
    origin = torch.tensor([0.2, -0.1, -4.0], dtype=torch.float64)
    ids = torch.arange(300)
    out = rt.transmittance_to_points(make_scene(s), origin, ids, return_hits=True)
    ref = transmittance_reference(*scene_args(s), origin, ids)
    torch.testing.assert_close(out.transmittance, ref.transmittance, rtol=1e-5, atol=1e-12)
    assert torch.equal(out.hit_count.long(), ref.hit_count.long())
    assert torch.equal(out.hits.gaussian_ids, ref.hits.gaussian_ids)
    assert float(out.transmittance.min()) < 0.5  # some targets are occluded
    rays = out.hits.ray_ids()
    assert not bool((out.hits.gaussian_ids.long() == ids[rays]).any())  # target itself excluded
    assert bool(((out.hits.t > 0) & (out.hits.t < 1)).all())  # only between point and target


def test_visibility_per_point_origins_and_rf_opacities():
    s = random_scene(200, seed=61)
    g = torch.Generator().manual_seed(2)
    ids = torch.randint(0, 200, (64,), generator=g)
    origins = torch.randn(64, 3, generator=g, dtype=torch.float64) * 3
    rf = torch.rand(200, generator=g, dtype=torch.float64).requires_grad_(True)
    scene = rt.GaussianScene(s["means"], s["log_scales"], s["rotations"], s["opacities"])
    v = rt.transmittance_to_points(scene, origins, ids, opacities=rf).transmittance
    rf_ref = rf.detach().clone().requires_grad_(True)
    v_ref = transmittance_reference(s["means"], s["log_scales"], s["rotations"], rf_ref, origins, ids).transmittance
    torch.testing.assert_close(v, v_ref, rtol=1e-5, atol=1e-12)
    w = torch.randn(64, generator=g, dtype=torch.float64)
    (v * w).sum().backward()
    (v_ref * w).sum().backward()
    torch.testing.assert_close(rf.grad, rf_ref.grad, rtol=1e-6, atol=1e-10)
    assert s["opacities"].grad is None


def test_visibility_degenerate_and_invalid():
    s = random_scene(50, seed=62)
    scene = make_scene(s)
    v = rt.transmittance_to_points(scene, s["means"][7], torch.tensor([7, 7]))
    assert torch.equal(v.transmittance, torch.ones(2, dtype=torch.float64))  # point at the target
    empty = rt.transmittance_to_points(scene, s["means"][0], torch.zeros(0, dtype=torch.long))
    assert empty.transmittance.shape == (0,)
    with pytest.raises(ValueError, match="gaussian_ids"):
        rt.transmittance_to_points(scene, s["means"][0], torch.tensor([50]))
    with pytest.raises(ValueError, match="gaussian_ids"):
        rt.transmittance_to_points(scene, s["means"][0], torch.tensor([0.5]))


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_one_pass_transmittance_equals_the_sorted_compositing(dtype):
    """trace_transmittance (hits multiplied in traversal order, no buffer) against trace and the oracle."""
    s = random_scene(400, seed=63, spread=1.5, scale=-2.0, dtype=dtype)
    g = torch.Generator().manual_seed(5)
    ids = torch.randint(0, 400, (500,), generator=g)
    origins = (torch.randn(500, 3, generator=g, dtype=torch.float64) * 3).to(dtype)
    d = s["means"][ids] - origins
    t_max = torch.rand(500, generator=g, dtype=torch.float64).to(dtype) * 1.2
    scene = make_scene(s)
    fast = rt.trace_transmittance(scene, origins, d, t_max=t_max, t_stop=0.0, exclude=ids)
    slow = rt.trace(scene, origins, d, t_max=t_max, t_stop=0.0, exclude=ids).transmittance
    tol = 1e-12 if dtype == torch.float64 else 1e-5
    torch.testing.assert_close(fast, slow, rtol=tol, atol=tol)
    if dtype == torch.float64:
        ref = transmittance_reference(*scene_args(s), origins, ids, t_stop=0.0).transmittance   # t_max = 1
        fast1 = rt.trace_transmittance(scene, origins, d, t_max=1.0, t_stop=0.0, exclude=ids)
        torch.testing.assert_close(fast1, ref, rtol=1e-5, atol=1e-12)
    assert float(fast.min()) < 0.05 < 0.95 < float(fast.max())
    # early stopping changes only rays that end below t_stop
    stopped = rt.trace_transmittance(scene, origins, d, t_max=t_max, t_stop=0.05, exclude=ids)
    keep = slow >= 0.05
    torch.testing.assert_close(stopped[keep], slow[keep], rtol=tol, atol=tol)
    assert bool((stopped[~keep] < 0.05).all()) and bool((~keep).any())


def test_one_pass_transmittance_opacities_and_checks():
    s = random_scene(100, seed=64)
    scene = make_scene(s)
    o, d = torch.zeros(3, dtype=torch.float64) - 3.0, torch.randn(20, 3, dtype=torch.float64)
    a = torch.rand(100, dtype=torch.float64)
    torch.testing.assert_close(rt.trace_transmittance(scene, o, d, opacities=a, t_stop=0.0),
                               rt.trace(scene, o, d, opacities=a, t_stop=0.0).transmittance, rtol=1e-12, atol=1e-14)
    assert rt.trace_transmittance(scene, o, d[:0]).shape == (0,)
    with pytest.raises(ValueError, match="opacities"):
        rt.trace_transmittance(scene, o, d, opacities=a * 2)
    with pytest.raises(ValueError, match="zero vector"):
        rt.trace_transmittance(scene, o, torch.zeros(2, 3, dtype=torch.float64))
