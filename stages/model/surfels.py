"""Geometry-only quantities of surfel Gaussians for physical optics (docs/physics.md section 8).

- `surfel_areas`: the surface area A_l each Gaussian stands for, so that a surface's total does not
  depend on how densely Gaussians tile it. A Gaussian's face-on cross-section is
  `A_face = pi sqrt(det Sigma) sqrt(n^T Sigma^-1 n)` (= pi s1 s2 for a flat one); surfels tiling a
  mesh are sized so that these add up to the mesh area (rfir_stages.geom.from_mesh). Gaussians that
  overlap more than such a tiling (geometry from photos, or a second layer) share their area: with
  the coverage `C(x) = sum_m exp(-0.5 (x - mu_m)^T Sigma_m^-1 (x - mu_m))` over Gaussians of the same
  surface (normals within 30 degrees, means within COPLANAR_M of the plane), whose mean over a tiled
  surface is 2 (each peak-normalised Gaussian integrates to 2 A_face), `A_l = A_face,l / max(1,
  Cbar_l / 2)` with `Cbar_l` the coverage averaged over Gaussian l's own weight, in its plane:

      Cbar_l = sum_m sqrt(det S_m / det(S_l + S_m)) exp(-0.5 d_lm^T (S_l + S_m)^-1 d_lm)

  (S the 2 x 2 in-plane covariances, d_lm the in-plane offset of the means; the self term is 1/2),
  then the largest Cbar among l and its close neighbours on the surface (overlap above half the
  self term). The average, not C at the mean: a tiling's coverage ripples between its Gaussians'
  peaks and C(mu_l) sits on a peak, which would leave a tiled plate short, while the ripple averages
  out of Cbar: the level does not depend on the density. Along an edge the coverage drops towards 1
  for want of neighbours, not of layers:
  the floor at 1 keeps a single layer's edge Gaussians at their own area, and the neighbours' value
  gives a doubled layer's edge the interior's sharing.
- `footprint_cells`: the rectangle cell a surfel stands for: its two in-plane axes (those of the
  Gaussian's covariance projected on its plane), sides in the ratio of the Gaussian's spreads along
  them and of area A_l. The physical-optics integral of a uniform current over the cell gives the
  footprint factor `F = sinc(k q.c_1) sinc(k q.c_2)` (`sinc x = sin x / x`, `c_i` the axis times half
  the side, `q = w_i + w_o`): the phase variation across a surfel. A tiling of such cells sums to
  the plate's exact integral (the cell's zeros fall on the tiling's grating lobes), so a plate's
  sidelobes (the edge returns a radar sees off the specular direction) keep their level at any
  spacing; a Gaussian weight instead tapers them by `exp(-0.5 k^2 q^T Sigma_w q)`, which leaves an
  object's off-specular returns low (docs/physics.md section 8.6).
"""
from __future__ import annotations

import math

import numpy as np
import torch

from rfir_core.physics.gaussian_rf import covariance, projected_cross_section_m2, quaternion_to_matrix

SAME_SURFACE_COS = math.cos(math.radians(30.0))
COPLANAR_M = 0.0015     # means closer than this to a surfel's plane lie on its surface (the faces of a 3 mm sheet stay apart)
NEIGHBOURS = 48
SQUARE_CELL_TOL = 1e-6   # spreads equal to this (relative): a square cell, its axes from the rotation


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
    n = normals / normals.norm(dim=-1, keepdim=True).clamp(min=1e-300)
    basis = _tangent_basis(n)                                            # [G, 3, 2]
    s_l = basis.transpose(1, 2) @ cov @ basis                            # [G, 2, 2] in l's plane
    s_m = torch.einsum("gia,gkij,gjb->gkab", basis, cov[idx], basis)     # [G, k, 2, 2] the neighbours, same plane
    d3 = means[idx] - means[:, None, :]                                  # [G, k, 3] mu_m - mu_l
    d = torch.einsum("gia,gki->gka", basis, d3)
    s_sum = s_l[:, None] + s_m
    overlap = torch.sqrt(torch.linalg.det(s_m).clamp(min=1e-300) / torch.linalg.det(s_sum).clamp(min=1e-300)) \
        * torch.exp(-0.5 * torch.einsum("gka,gkab,gkb->gk", d, torch.linalg.inv(s_sum), d))
    same = ((n[:, None, :] * n[idx]).sum(-1).abs() >= SAME_SURFACE_COS) \
        & ((d3 * n[:, None, :]).sum(-1).abs() < COPLANAR_M)
    coverage = (overlap * same).sum(1)                                   # Cbar_l
    close = same & (overlap > 0.25)                                      # includes l itself (its self term is 1/2)
    coverage = torch.where(close, coverage[idx], torch.zeros_like(overlap)).max(1).values
    return a_face / torch.clamp(coverage / 2.0, min=1.0)


def _tangent_basis(n: torch.Tensor) -> torch.Tensor:
    """[G, 3, 2]: two orthonormal vectors in the plane of each unit normal n [G, 3]."""
    ref = torch.zeros_like(n)
    use_x = n[:, 0].abs() < 0.9
    ref[use_x, 0] = 1.0
    ref[~use_x, 1] = 1.0
    t1 = torch.linalg.cross(n, ref, dim=-1)
    t1 = t1 / t1.norm(dim=-1, keepdim=True)
    return torch.stack([t1, torch.linalg.cross(n, t1, dim=-1)], -1)


def footprint_cells(log_scales: torch.Tensor, rotations: torch.Tensor, normals: torch.Tensor,
                    areas_m2: torch.Tensor) -> torch.Tensor:
    """C [G, 2, 3] m: each surfel's cell axes (unit, in its plane) times half the cell's sides (see the
    module docstring); the footprint factor of a pair with q [3] is footprint_factor(C q, k)."""
    cov = covariance(log_scales, rotations)
    n = normals / normals.norm(dim=-1, keepdim=True).clamp(min=1e-300)
    proj = torch.eye(3, dtype=cov.dtype) - n[:, :, None] * n[:, None, :]
    evals, evecs = torch.linalg.eigh(proj @ cov @ proj)              # ascending; the smallest is along n
    v1, v2 = evals[:, 2].clamp(min=1e-300), evals[:, 1].clamp(min=1e-300)
    ratio = torch.sqrt(v1 / v2).clamp(max=1e3)                       # side_1 / side_2
    side2 = torch.sqrt(areas_m2 / ratio)
    side1 = areas_m2 / side2.clamp(min=1e-300)
    axis1, axis2 = evecs[:, :, 2], evecs[:, :, 1]
    # equal spreads leave the covariance's axes undetermined: a square cell's sides follow the Gaussian's
    # first axis (a mesh's square cells, rfir_stages.geom.from_mesh, are laid along their rectangle's sides)
    first = (proj @ quaternion_to_matrix(rotations)[:, :, 0:1])[:, :, 0]
    first = first / first.norm(dim=-1, keepdim=True).clamp(min=1e-300)
    square = ((ratio - 1.0).abs() < SQUARE_CELL_TOL)[:, None]
    axis1 = torch.where(square, first, axis1)
    axis2 = torch.where(square, torch.linalg.cross(n, first), axis2)
    return torch.stack([axis1 * (0.5 * side1)[:, None], axis2 * (0.5 * side2)[:, None]], 1)


def footprint_factor(q_cell: torch.Tensor, k0: torch.Tensor) -> torch.Tensor:
    """F [P, K]: the cell footprint factor sinc(k q.c_1) sinc(k q.c_2) for q_cell [P, 2] m (= C q) and
    wavenumbers k0 [K] rad/m (sinc x = sin x / x; torch.sinc is sin(pi x) / (pi x))."""
    x = q_cell[:, None, :] * k0[None, :, None] / math.pi              # [P, K, 2]
    return torch.sinc(x).prod(-1)
