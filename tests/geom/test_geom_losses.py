"""Losses of `rfir geom`: SSIM against hand-computed values, pseudo-normals of a rendered plane, the
depth-uncertainty and smoothness terms on cases with known answers."""
import math

import numpy as np
import pytest
import torch

from rfir_stages.geom.losses import (SSIM_C1, SSIM_C2, depth_uncertainty_loss, gaussian_window, normal_smoothness_loss,
                                     pseudo_normals, ssim, surface_mask)
from rfir_stages.geom.model import GaussianModel, logit
from rfir_stages.geom.gaussian_views import make_scene, render_view


def test_ssim_matches_a_hand_computed_window():
    rng = np.random.default_rng(0)
    x = rng.random((11, 11, 1))
    y = np.clip(0.7 * x + 0.2 + 0.05 * rng.standard_normal((11, 11, 1)), 0, 1)
    # By hand: one 11 x 11 window, Gaussian weights sigma 1.5.
    t = np.arange(11) - 5.0
    g = np.exp(-t**2 / (2 * 1.5**2))
    w = np.outer(g, g) / np.outer(g, g).sum()
    a, b = x[..., 0], y[..., 0]
    mx, my = (w * a).sum(), (w * b).sum()
    vx, vy = (w * a * a).sum() - mx**2, (w * b * b).sum() - my**2
    cxy = (w * a * b).sum() - mx * my
    want = (2 * mx * my + 1e-4) * (2 * cxy + 9e-4) / ((mx**2 + my**2 + 1e-4) * (vx + vy + 9e-4))
    got = float(ssim(torch.as_tensor(x), torch.as_tensor(y)))
    assert got == pytest.approx(want, abs=1e-9)
    assert 0.3 < want < 0.99


def test_ssim_of_constant_images_is_the_luminance_term():
    a, b = 0.3, 0.6
    x = torch.full((16, 20, 3), a, dtype=torch.float64)
    y = torch.full((16, 20, 3), b, dtype=torch.float64)
    want = (2 * a * b + SSIM_C1) / (a * a + b * b + SSIM_C1)
    assert float(ssim(x, y)) == pytest.approx(want, rel=1e-9)
    assert float(ssim(x, x)) == pytest.approx(1.0)
    assert float(gaussian_window().sum()) == pytest.approx(1.0, abs=1e-6)
    assert SSIM_C2 == pytest.approx(9e-4)


def _camera(eye, target, width=48, height=40, fov_deg=50.0):
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, [0, 0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    f = 0.5 * width / math.tan(math.radians(fov_deg) / 2)
    v, u = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    cam = np.stack([(u - (width - 1) / 2) / f, (v - (height - 1) / 2) / f, np.ones_like(u, dtype=float)], -1)
    d = cam @ np.stack([x, y, z], 1).T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return torch.as_tensor(eye), torch.as_tensor(d)


def test_pseudo_normal_of_an_analytic_plane_is_its_normal():
    n = np.array([0.3, -0.2, 1.0])
    n /= np.linalg.norm(n)
    origin, dirs = _camera([0.4, -0.5, 0.8], [0, 0, 0])
    # distance along each ray to the plane n . x = 0
    t = -(origin @ torch.as_tensor(n)) / (dirs @ torch.as_tensor(n))
    pn = pseudo_normals(t, dirs, origin)
    cos = (pn @ torch.as_tensor(n)).numpy()  # the camera is on the +n side
    assert np.all(cos > 1 - 1e-9)


def test_pseudo_normal_of_a_rendered_gaussian_plane_is_the_plane_normal():
    # A tilted plane tiled with flat Gaussians (surfels), rendered through the tracer.
    normal = np.array([0.0, np.sin(0.4), np.cos(0.4)])
    e1 = np.array([1.0, 0.0, 0.0])
    e2 = np.cross(normal, e1)
    s = np.linspace(-0.15, 0.15, 31)
    uu, vv = np.meshgrid(s, s)
    means = uu.reshape(-1, 1) * e1 + vv.reshape(-1, 1) * e2
    rot = np.stack([e1, e2, normal], -1)
    from rfir_stages.geom.from_mesh import _quat_from_matrix

    m = len(means)
    params = {"means": torch.tensor(means, dtype=torch.float32),
              "log_scales": torch.log(torch.tensor([[0.008, 0.008, 0.0004]] * m)),
              "rotations": torch.tensor(_quat_from_matrix(np.repeat(rot[None], m, 0)), dtype=torch.float32),
              "opacity_logits": torch.full((m,), float(logit(0.95))),
              "color_logits": torch.zeros(m, 3), "normals_raw": torch.tensor(np.repeat(normal[None], m, 0), dtype=torch.float32)}
    model = GaussianModel(params, {})
    origin, dirs = _camera([0.05, 0.45, 0.6], [0, 0, 0])
    with torch.no_grad():
        r = render_view(make_scene(model, 1 / 255), model, origin.float(), dirs.float(), torch.zeros(3))
    pn = pseudo_normals(r.expected_depth(), dirs.float(), origin.float())
    mask = surface_mask(r.acc, 0.9)
    assert int(mask.sum()) > 300
    cos = (pn[mask] @ torch.tensor(normal, dtype=torch.float32)).numpy()
    angle = np.degrees(np.arccos(np.clip(cos, -1, 1)))
    assert np.median(angle) < 2.0
    # The rendered normal map faces the camera and agrees too.
    rn = torch.nn.functional.normalize(r.normal[1:-1, 1:-1][mask], dim=-1) @ torch.tensor(normal, dtype=torch.float32)
    assert float(rn.min()) > 0.99


def test_depth_uncertainty_is_the_depth_variance():
    # Two hits at 1 m and 2 m with weights 0.5 each: D = 1.5, D_sq = 2.5, variance 0.25.
    d = torch.tensor([[1.5]])
    dsq = torch.tensor([[2.5]])
    assert float(depth_uncertainty_loss(d, dsq, ref_distance_m=0.5)) == pytest.approx(0.25 / 0.25)
    assert float(depth_uncertainty_loss(d, d * d, ref_distance_m=1.0)) == pytest.approx(0.0)


def test_normal_smoothness_is_zero_for_constant_normals_and_relaxed_at_photo_edges():
    n = torch.zeros(8, 8, 3)
    n[..., 2] = 1
    img = torch.rand(8, 8, 3)
    assert float(normal_smoothness_loss(n, img)) == 0.0
    n2 = n.clone()
    n2[:, 4:, 0] = 1.0  # a crease between columns 3 and 4
    flat = torch.zeros(8, 8, 3)
    edge = flat.clone()
    edge[:, 4:] = 1.0  # the photo has an edge at the same place
    assert float(normal_smoothness_loss(n2, edge)) < float(normal_smoothness_loss(n2, flat))
