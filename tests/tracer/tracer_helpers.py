"""Shared scene and ray generators for the tracer tests (small, seeded, float64 by default)."""
from __future__ import annotations

import torch

FIELDS = ("features", "depth", "depth_sq", "normal", "transmittance")


def random_scene(n: int, seed: int = 0, dtype=torch.float64, k: int = 4, flat: bool = False,
                 spread: float = 1.0, scale: float = -1.5):
    """Gaussians in a cube of half-size `spread` (metres), anisotropic, random orientation."""
    g = torch.Generator().manual_seed(seed)
    means = (torch.rand(n, 3, generator=g, dtype=torch.float64) * 2 - 1) * spread
    log_scales = torch.randn(n, 3, generator=g, dtype=torch.float64) * 0.35 + scale
    if flat:
        log_scales[:, 2] = -12.0
    rotations = torch.randn(n, 4, generator=g, dtype=torch.float64)
    opacities = torch.rand(n, generator=g, dtype=torch.float64) * 0.95
    normals = torch.nn.functional.normalize(torch.randn(n, 3, generator=g, dtype=torch.float64), dim=1)
    features = torch.rand(n, k, generator=g, dtype=torch.float64)
    out = dict(means=means, log_scales=log_scales, rotations=rotations, opacities=opacities,
               normals=normals, features=features)
    return {key: v.to(dtype) for key, v in out.items()}


def random_rays(r: int, seed: int = 1, dtype=torch.float64, distance: float = 4.0, jitter: float = 0.5):
    """Rays from points near (0, 0, -distance) towards the origin's neighbourhood, unit directions."""
    g = torch.Generator().manual_seed(seed)
    o = torch.randn(r, 3, generator=g, dtype=torch.float64) * 0.3
    o[:, 2] -= distance
    target = (torch.rand(r, 3, generator=g, dtype=torch.float64) * 2 - 1) * jitter
    d = torch.nn.functional.normalize(target - o, dim=1)
    return o.to(dtype), d.to(dtype)


def scene_args(s: dict):
    return (s["means"], s["log_scales"], s["rotations"], s["opacities"])


def make_scene(s: dict, **kw):
    import rfir_tracer as rt

    return rt.GaussianScene(s["means"], s["log_scales"], s["rotations"], s["opacities"], s["normals"], **kw)


def assert_results_close(a, b, rtol=1e-5, atol=1e-9):
    """Compare two TraceResults field by field (b is usually the float64 reference)."""
    for f in FIELDS:
        x, y = getattr(a, f), getattr(b, f)
        torch.testing.assert_close(x.to(torch.float64), y.to(torch.float64), rtol=rtol, atol=atol, msg=f)
    assert torch.equal(a.hit_count.to(torch.int64), b.hit_count.to(torch.int64))
