"""transmittance_to_points: incident-field visibility (PHYSICS.md RF step 1)."""
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
