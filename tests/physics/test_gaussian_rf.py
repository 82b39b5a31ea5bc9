"""A Gaussian's covariance and projected cross-section against closed forms (docs/physics.md sections 2 and 8.6)."""
import math

import numpy as np
import pytest
import torch

from rfir_core.physics.gaussian_rf import covariance, projected_cross_section_m2


@pytest.fixture(autouse=True)
def _float64():
    """These closed-form checks run in float64; restore the default so other tests see torch's own."""
    before = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)
    yield
    torch.set_default_dtype(before)


def disc(n=1, scale=0.05, flat=1e-4):
    """n flat Gaussians in the plane x = 0 (normal +x), spaced along y."""
    means = torch.zeros(n, 3)
    means[:, 1] = torch.linspace(-(n - 1) / 2, (n - 1) / 2, n) * 2 * scale
    log_scales = torch.log(torch.tensor([[flat, scale, scale]])).expand(n, 3)
    quats = torch.tensor([[1.0, 0, 0, 0]]).expand(n, 4)
    return means, covariance(log_scales, quats), torch.tensor([[1.0, 0, 0]]).expand(n, 3)


def test_projected_cross_section_sphere_and_tilted_disc():
    s = 0.2
    cov = covariance(torch.full((1, 3), math.log(s)), torch.tensor([[0.3, 0.1, -0.5, 0.8]]))
    u = torch.nn.functional.normalize(torch.randn(5, 1, 3), dim=-1)
    np.testing.assert_allclose(projected_cross_section_m2(cov, u), math.pi * s * s, rtol=1e-10)
    _, cov, _ = disc(scale=0.1)
    for theta in (0.0, 0.5, 1.2):
        u = torch.tensor([[[math.cos(theta), math.sin(theta), 0.0]]])
        np.testing.assert_allclose(projected_cross_section_m2(cov, u)[0, 0], math.pi * 0.01 * math.cos(theta),
                                   rtol=1e-4)
