"""Degenerate inputs give defined results or a clear ValueError."""
import math

import pytest
import torch
from tracer_helpers import assert_results_close, make_scene, random_rays, random_scene, scene_args

import rfir_tracer as rt
from rfir_tracer.reference import trace_reference


def _ref(s, o, d, **kw):
    return trace_reference(*scene_args(s), o, d, features=s["features"], normals=s["normals"], **kw)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_flat_gaussians(dtype):
    s = random_scene(150, seed=50, flat=True)  # one axis at exp(-12) ~ 6e-6 m
    o, d = random_rays(400, seed=51)
    sd = {k: v.to(dtype) for k, v in s.items()}
    out = rt.trace(make_scene(sd), o.to(dtype), d.to(dtype), features=sd["features"])
    for f in ("features", "depth", "normal", "transmittance"):
        assert bool(torch.isfinite(getattr(out, f)).all()), f
    assert int(out.hit_count.sum()) > 100
    if dtype == torch.float64:  # the reference's literal Sigma^-1 = R S^-2 R^T (S^-2 ~ 3e10) loses ~1e-7
        assert_results_close(out, _ref(s, o, d), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_extremely_flat_gaussians_tend_to_discs(dtype):
    """log-scale -40 (the literal reference formula overflows there) behaves like -20: a disc."""
    s = {k: v.to(dtype) for k, v in random_scene(150, seed=58, flat=True).items()}
    o, d = random_rays(400, seed=59, dtype=dtype)
    res = []
    for ls in (-20.0, -40.0):
        s["log_scales"][:, 2] = ls
        res.append(rt.trace(make_scene(s), o, d, features=s["features"]))
    assert int(res[1].hit_count.sum()) > 100
    assert torch.equal(res[0].hit_count, res[1].hit_count)
    tol = 1e-9 if dtype == torch.float64 else 1e-4
    for f in ("features", "depth", "normal", "transmittance"):
        torch.testing.assert_close(getattr(res[1], f), getattr(res[0], f), rtol=tol, atol=tol, msg=f)


def test_rays_starting_inside_gaussians():
    s = random_scene(60, seed=52, scale=-0.8)
    g = torch.Generator().manual_seed(0)
    o = s["means"][:40] + 0.01 * torch.randn(40, 3, generator=g, dtype=torch.float64)
    d = torch.nn.functional.normalize(torch.randn(40, 3, generator=g, dtype=torch.float64), dim=1)
    out = rt.trace(make_scene(s), o, d, features=s["features"])  # t_min = 0: peaks behind are skipped
    assert_results_close(out, _ref(s, o, d))
    both = rt.trace(make_scene(s), o, d, features=s["features"], t_min=-math.inf)
    assert_results_close(both, _ref(s, o, d, t_min=-math.inf))


def test_zero_gaussians():
    z = torch.zeros(0, 3, dtype=torch.float64, requires_grad=True)
    scene = rt.GaussianScene(z, torch.zeros(0, 3, dtype=torch.float64), torch.zeros(0, 4, dtype=torch.float64))
    o, d = random_rays(5)
    out = rt.trace(scene, o, d, features=torch.zeros(0, 2, dtype=torch.float64), return_hits=True)
    assert torch.equal(out.transmittance, torch.ones(5, dtype=torch.float64))
    assert out.features.shape == (5, 2) and float(out.features.detach().abs().sum()) == 0.0
    assert out.hits.num_hits == 0 and int(out.hit_count.sum()) == 0
    out.depth.sum().backward()
    assert z.grad.shape == (0, 3)


def test_rays_that_hit_nothing_and_zero_rays():
    s = random_scene(50, seed=53)
    scene = make_scene(s)
    o = torch.tensor([[0.0, 0.0, 10.0]], dtype=torch.float64).repeat(4, 1)
    d = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0, 0], [0, 1.0, 0], [0.0, 0.0, 1e-9]], dtype=torch.float64)
    out = rt.trace(scene, o, d, features=s["features"])
    assert torch.equal(out.transmittance, torch.ones(4, dtype=torch.float64))
    assert float(out.depth.abs().sum() + out.normal.abs().sum() + out.features.abs().sum()) == 0.0
    empty = rt.trace(scene, torch.zeros(3, dtype=torch.float64), torch.zeros(0, 3, dtype=torch.float64))
    assert empty.depth.shape == (0,)
    none = rt.trace(scene, *random_rays(10), t_min=2.0, t_max=2.0)  # empty interval
    assert int(none.hit_count.sum()) == 0


def test_axis_aligned_rays_through_axis_aligned_boxes():
    """Zero direction components give inf in the slab test; hits must still be exact."""
    s = random_scene(100, seed=54)
    s["rotations"] = torch.tensor([[1.0, 0, 0, 0]], dtype=torch.float64).repeat(100, 1)
    g = torch.Generator().manual_seed(1)
    o = torch.rand(64, 3, generator=g, dtype=torch.float64) * 2 - 1
    o[:, 2] = -5.0
    d = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64).repeat(64, 1)
    o[:8, 0] = s["means"][:8, 0]  # origins exactly on box-centre planes
    out = rt.trace(make_scene(s), o, d, features=s["features"])
    assert_results_close(out, _ref(s, o, d))


@pytest.mark.parametrize("field", ["means", "log_scales", "rotations", "opacities", "normals"])
def test_nan_in_scene_raises(field):
    s = random_scene(20, seed=55)
    s[field][3].fill_(math.nan)
    with pytest.raises(ValueError, match=field):
        make_scene(s)


def test_nan_in_rays_or_features_raises():
    s = random_scene(20, seed=56)
    scene = make_scene(s)
    o, d = random_rays(8)
    bad = d.clone()
    bad[2, 1] = math.nan
    with pytest.raises(ValueError, match="directions"):
        rt.trace(scene, o, bad)
    bad_o = o.clone()
    bad_o[0, 0] = math.inf
    with pytest.raises(ValueError, match="origins"):
        rt.trace(scene, bad_o, d)
    f = s["features"].clone()
    f[0, 0] = math.nan
    with pytest.raises(ValueError, match="features"):
        rt.trace(scene, o, d, features=f)
    with pytest.raises(ValueError, match="t_max"):
        rt.trace(scene, o, d, t_max=math.nan)
    with torch.no_grad():  # NaN written in place after construction is caught at the next trace
        s["means"][0, 0] = math.nan
    with pytest.raises(ValueError, match="means"):
        rt.trace(scene, o, d)


def test_invalid_values_raise():
    s = random_scene(20, seed=57)
    scene = make_scene(s)
    o, d = random_rays(8)
    with pytest.raises(ValueError, match="zero vector"):
        rt.trace(scene, o, torch.zeros_like(d))
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        rt.trace(scene, o, d, opacities=s["opacities"] + 1.0)
    with pytest.raises(ValueError, match="alpha_min"):
        rt.trace(scene, o, d, alpha_min=0.0)
    with pytest.raises(ValueError, match="t_stop"):
        rt.trace(scene, o, d, t_stop=1.5)
    q = s["rotations"].clone()
    q[1] = 0.0
    with pytest.raises(ValueError, match="quaternion"):
        rt.GaussianScene(s["means"], s["log_scales"], q)
    with pytest.raises(ValueError, match="shape"):
        rt.GaussianScene(s["means"], s["log_scales"][:, :2], s["rotations"])
    with pytest.raises(ValueError, match="rows"):
        rt.trace(scene, o, d, features=s["features"][:5])
    with pytest.raises(ValueError, match="broadcast"):
        rt.trace(scene, o[:3], d)
    with pytest.raises(TypeError):
        rt.trace(s["means"], o, d)
