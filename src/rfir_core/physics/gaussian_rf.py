"""Geometry of a 3D Gaussian used by the radio model (docs/physics.md sections 4 and 8.6), in torch:
its rotation, covariance and projected cross-section. Positions in metres, world frame; G Gaussians.
"""
from __future__ import annotations

import math

import torch



def quaternion_to_matrix(quat_wxyz: torch.Tensor) -> torch.Tensor:
    """[..., 4] (w, x, y, z), normalised inside -> rotation matrices [..., 3, 3]."""
    q = quat_wxyz / quat_wxyz.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(q.shape[:-1] + (3, 3))


def covariance(log_scales: torch.Tensor, quat_wxyz: torch.Tensor) -> torch.Tensor:
    """Sigma = R S S^T R^T from log standard deviations [G, 3] [log m] and quaternions [G, 4] -> [G, 3, 3] [m^2]."""
    rot = quaternion_to_matrix(quat_wxyz)
    scaled = rot * torch.exp(log_scales)[..., None, :]
    return scaled @ scaled.transpose(-1, -2)


def projected_cross_section_m2(cov_m2: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
    """A = pi sqrt(det Sigma) sqrt(u^T Sigma^-1 u): the Gaussian's area seen along unit `direction`.

    cov_m2: [G, 3, 3]; direction: [..., G, 3] unit vectors -> [..., G] in m^2 (pi s^2 for a sphere of std s).
    Uses the scales directly would be cheaper, but this form is exact for any covariance.
    """
    inv = torch.linalg.inv(cov_m2)
    quad = torch.einsum("...gi,gij,...gj->...g", direction, inv, direction)
    return math.pi * torch.sqrt(torch.linalg.det(cov_m2)) * torch.sqrt(quad)
