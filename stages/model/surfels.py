"""Geometry-only quantities of surfel Gaussians for physical optics (docs/physics.md section 8).

- `surfel_areas`: the surface area A_l each Gaussian stands for, so that a surface's total does not
  depend on how densely Gaussians tile it. A Gaussian's face-on cross-section is
  `A_face = pi sqrt(det Sigma) sqrt(n^T Sigma^-1 n)` (= pi s1 s2 for a flat one); surfels tiling a
  mesh are sized so that these add up to the mesh area (rfir_stages.geom.from_mesh). Gaussians that
  overlap more than such a tiling (geometry from photos, or a second layer) share their area: with
  the coverage `C(x) = sum_m exp(-0.5 (x - mu_m)^T Sigma_m^-1 (x - mu_m))` over Gaussians of the same
  surface (normals within 30 degrees), whose mean over a tiled surface is 2 (each peak-normalised
  Gaussian integrates to 2 A_face), `A_l = A_face,l / max(1, C(mu_l) / 2)`. The floor at 1 keeps
  the Gaussians along an edge (where C drops towards 1) at their own area.
- `footprint_covariance`: the covariance of a Gaussian weight of integral A_l with the shape of the
  Gaussian, `Sigma_w = (A_l / (2 A_face,l)) Sigma`. Its Fourier transform gives the surfel's
  physical-optics footprint factor `exp(-0.5 k^2 q^T Sigma_w q)`, `q = w_i + w_o`: the phase
  variation across a surfel, which suppresses the grating lobes of a discrete tiling and makes a
  tilted plate's sinc lobes come out right when the spacing is below about lambda / 4.
"""
from __future__ import annotations

import math

import numpy as np
import torch

from rfir_cli.physics.gaussian_rf import covariance, projected_cross_section_m2

SAME_SURFACE_COS = math.cos(math.radians(30.0))
NEIGHBOURS = 48


def face_on_area_m2(cov: torch.Tensor, normals: torch.Tensor) -> torch.Tensor:
    """A_face [G] m^2: a Gaussian's projected cross-section along its normal."""
    return projected_cross_section_m2(cov, normals)


def surfel_areas(means: torch.Tensor, log_scales: torch.Tensor, rotations: torch.Tensor,
                 normals: torch.Tensor) -> torch.Tensor:
    """A_l [G] m^2 (see the module docstring). Inputs: means [G, 3] m, log_scales [G, 3],
    rotations [G, 4] wxyz, normals [G, 3] unit."""
    from scipy.spatial import cKDTree

    cov = covariance(log_scales, rotations)
    a_face = face_on_area_m2(cov, normals)
    g = means.shape[0]
    if g < 2:
        return a_face
    k = min(NEIGHBOURS, g)
    pts = means.detach().numpy()
    _, idx = cKDTree(pts).query(pts, k=k)
    idx = torch.as_tensor(np.asarray(idx).reshape(g, k))
    inv = torch.linalg.inv(cov)
    d = means[:, None, :] - means[idx]                                   # [G, k, 3] mu_l - mu_m
    maha = torch.einsum("gki,gkij,gkj->gk", d, inv[idx], d)
    same = (normals[:, None, :] * normals[idx]).sum(-1).abs() >= SAME_SURFACE_COS
    coverage = (torch.exp(-0.5 * maha) * same).sum(1)
    return a_face / torch.clamp(coverage / 2.0, min=1.0)


def footprint_covariance(log_scales: torch.Tensor, rotations: torch.Tensor, normals: torch.Tensor,
                         areas_m2: torch.Tensor) -> torch.Tensor:
    """Sigma_w [G, 3, 3] m^2: the Gaussian's covariance scaled to a weight of integral A_l."""
    cov = covariance(log_scales, rotations)
    scale = areas_m2 / (2.0 * face_on_area_m2(cov, normals)).clamp(min=1e-300)
    return cov * scale[:, None, None]
