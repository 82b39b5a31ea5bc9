"""Backward pass: analytic gradients against the reference's autograd, and gradcheck."""
import pytest
import torch
from tracer_helpers import FIELDS, random_rays, random_scene

import rfir_tracer as rt
from rfir_tracer.reference import trace_reference

PARAMS = ("means", "log_scales", "rotations", "opacities", "normals", "features")


def _leaves(s):
    return {k: s[k].clone().requires_grad_(True) for k in PARAMS}


def _loss(res, weights):
    return sum((getattr(res, f) * w).sum() for f, w in zip(FIELDS, weights))


def _weights(r, k, seed, dtype=torch.float64):
    g = torch.Generator().manual_seed(seed)
    shapes = [(r, k), (r,), (r,), (r, 3), (r,)]
    return [torch.randn(*sh, generator=g, dtype=torch.float64).to(dtype) for sh in shapes]


def _native(p, o, d, **kw):
    scene = rt.GaussianScene(p["means"], p["log_scales"], p["rotations"], p["opacities"], p["normals"])
    return rt.trace(scene, o, d, features=p["features"], **kw)


def _reference(p, o, d, **kw):
    return trace_reference(p["means"], p["log_scales"], p["rotations"], p["opacities"], o, d,
                           features=p["features"], normals=p["normals"], **kw)


@pytest.mark.parametrize("seed", [0, 1])
def test_gradients_match_reference(seed):
    s = random_scene(100, seed=30 + seed)
    o, d = random_rays(300, seed=40 + seed)
    w = _weights(300, 4, seed)
    w[2] = w[2] * 0.1  # depth_sq is large; keep all terms comparable
    a, b = _leaves(s), _leaves(s)
    ga = torch.autograd.grad(_loss(_native(a, o, d), w), [a[k] for k in PARAMS])
    gb = torch.autograd.grad(_loss(_reference(b, o, d), w), [b[k] for k in PARAMS])
    for name, x, y in zip(PARAMS, ga, gb):
        assert float(y.abs().max()) > 0, name
        torch.testing.assert_close(x, y, rtol=1e-6, atol=1e-8 * float(y.abs().max()), msg=name)


def test_gradients_with_limits_stop_and_clamp():
    """t limits, early stop and the 0.99 alpha clamp (opacities near 1) in the gradients."""
    s = random_scene(100, seed=33)
    s["opacities"] = 0.9 + 0.1 * torch.rand(100, dtype=torch.float64)
    o, d = random_rays(200, seed=34)
    kw = dict(t_min=3.0, t_max=5.5, t_stop=0.2, alpha_min=0.01)
    w = _weights(200, 4, 2)
    a, b = _leaves(s), _leaves(s)
    ga = torch.autograd.grad(_loss(_native(a, o, d, **kw), w), [a[k] for k in PARAMS])
    gb = torch.autograd.grad(_loss(_reference(b, o, d, **kw), w), [b[k] for k in PARAMS])
    for name, x, y in zip(PARAMS, ga, gb):
        torch.testing.assert_close(x, y, rtol=1e-6, atol=1e-8 * float(y.abs().max() + 1), msg=name)


def test_gradcheck_tiny_scene():
    s = random_scene(6, seed=35, spread=0.4, scale=-1.0)
    s["opacities"] = 0.2 + 0.6 * torch.rand(6, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    o, d = random_rays(10, seed=36, jitter=0.3)
    w = _weights(10, 4, 3)

    def fn(*params):
        p = dict(zip(PARAMS, params))
        return _loss(_native(p, o, d), w)

    inputs = tuple(s[k].clone().requires_grad_(True) for k in PARAMS)
    assert int(_native(s, o, d).hit_count.sum()) >= 10  # the rays do hit the Gaussians
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-6, atol=1e-5, rtol=1e-4)


def test_gradcheck_flat_and_visibility():
    """Flat Gaussians on visibility segments. The segments' end points (the targets' means) are
    held fixed: the tracer gives no gradient through ray origins or directions, by design."""
    s = random_scene(6, seed=37, spread=0.4, scale=-1.0, flat=True)
    s["log_scales"][:, 2] = -6.0  # flat but inside gradcheck's finite-difference range
    ids = torch.arange(6)
    origin = torch.tensor([0.05, -0.03, -3.0], dtype=torch.float64)
    d = s["means"] - origin

    def fn(means, log_scales, rotations, opacities):
        scene = rt.GaussianScene(means, log_scales, rotations, opacities)
        return rt.trace(scene, origin, d, t_min=0.0, t_max=1.0, exclude=ids).transmittance

    inputs = tuple(s[k].clone().requires_grad_(True) for k in PARAMS[:4])
    assert float(fn(*inputs).detach().min()) < 0.9  # segments do pass through other Gaussians
    assert torch.autograd.gradcheck(fn, inputs, eps=1e-7, atol=1e-5, rtol=1e-4, fast_mode=True)

    def vis(log_scales, rotations, opacities):
        scene = rt.GaussianScene(s["means"], log_scales, rotations)
        return rt.transmittance_to_points(scene, origin, ids, opacities=opacities).transmittance

    assert torch.autograd.gradcheck(vis, inputs[1:], eps=1e-7, atol=1e-5, rtol=1e-4, fast_mode=True)


def test_float32_gradients_close_to_float64():
    s = random_scene(100, seed=38)
    o, d = random_rays(200, seed=39)
    w = _weights(200, 4, 4)
    w[2] = w[2] * 0.1
    a = _leaves(s)
    b = _leaves({k: v.float() for k, v in s.items()})
    ga = torch.autograd.grad(_loss(_native(a, o, d), w), [a[k] for k in PARAMS])
    gb = torch.autograd.grad(_loss(_native(b, o.float(), d.float()), [x.float() for x in w]),
                             [b[k] for k in PARAMS])
    for name, x, y in zip(PARAMS, ga, gb):
        assert y.dtype == torch.float32
        err = float((x - y.double()).norm() / x.norm())
        assert err < 1e-3, (name, err)


def test_opacity_override_receives_gradient():
    s = random_scene(80, seed=41)
    o, d = random_rays(100, seed=42)
    scene = rt.GaussianScene(s["means"], s["log_scales"], s["rotations"], s["opacities"])
    rf = torch.rand(80, dtype=torch.float64, requires_grad=True)
    out = rt.trace(scene, o, d, opacities=rf)
    out.transmittance.sum().backward()
    ref_rf = rf.detach().clone().requires_grad_(True)
    trace_reference(s["means"], s["log_scales"], s["rotations"], ref_rf, o, d).transmittance.sum().backward()
    torch.testing.assert_close(rf.grad, ref_rf.grad, rtol=1e-6, atol=1e-10)


def test_backward_is_deterministic():
    s = random_scene(200, seed=43)
    o, d = random_rays(2000, seed=44)
    grads = []
    for _ in range(2):
        p = _leaves(s)
        _native(p, o, d).depth.sum().backward()
        grads.append(p["means"].grad)
    assert torch.equal(grads[0], grads[1])
