"""GaussianScene: the Gaussians' tensors plus the BVH the tracer walks.

The BVH bounds each Gaussian by the ellipsoid ``maha <= kappa^2`` with
``kappa^2 = 2 ln(1 / alpha_min)``: exactly where ``alpha >= alpha_min`` can hold for any opacity
<= 1 (3.33 sigma for the default 1/255). The bounds therefore depend on geometry only, never on
opacities, so visual and RF opacities share one BVH.

When the geometry tensors change in place (an optimiser step) the scene notices through the
tensors' version counters and refits the bounds before the next trace; after large motions call
``rebuild()`` for a fresh SAH tree. Tracing with a smaller ``alpha_min`` than the BVH was built for
refits it with the wider bounds automatically.
"""
from __future__ import annotations

import math

import torch

from . import _checks
from ._ext import native


class GaussianScene:
    """Gaussians (geometry, opacities, normals) and their BVH.

    Args:
        means: [N, 3] centres, metres (world frame).
        log_scales: [N, 3] natural log of the standard deviations along the principal axes, log m.
        rotations: [N, 4] quaternions wxyz (normalised inside; any non-zero norm).
        opacities: [N] activated opacities in [0, 1] (the caller applies the sigmoid). Default 1.
        normals: [N, 3] unit normals, or None (the normal output is then zero).
        alpha_min: smallest alpha a hit may have; sets the BVH bounds (default 1/255).
        leaf_size: maximum Gaussians per BVH leaf.

    Tensors may require grad; gradients flow to them through ``rfir_tracer.trace``.
    """

    def __init__(self, means, log_scales, rotations, opacities=None, normals=None, *,
                 alpha_min: float = 1.0 / 255.0, leaf_size: int = 4):
        _checks.check_geometry(means, log_scales, rotations)
        n = means.shape[0]
        if opacities is None:
            opacities = torch.ones(n, dtype=means.dtype, device=means.device)
        _checks.check_opacities(opacities, n)
        if normals is not None:
            _checks.check_matrix(normals, "normals", 3, n)
            _checks.check_finite(normals, "normals")
        _checks.check_params(alpha_min, 0.0)
        self.means, self.log_scales, self.rotations = means, log_scales, rotations
        self.opacities, self.normals = opacities, normals
        self.leaf_size = int(leaf_size)
        self.bvh_alpha_min = float(alpha_min)
        self.rebuild()

    # ------------------------------------------------------------------ BVH maintenance
    @property
    def num_gaussians(self) -> int:
        return int(self.means.shape[0])

    @property
    def device(self) -> torch.device:
        return self.means.device

    @property
    def dtype(self) -> torch.dtype:
        return self.means.dtype

    def _kappa(self) -> float:
        return math.sqrt(_checks.kappa2(self.bvh_alpha_min))

    def _geometry_key(self):
        return tuple((id(t), t._version) for t in (self.means, self.log_scales, self.rotations))

    def rebuild(self) -> "GaussianScene":
        """Build a fresh SAH BVH from the current geometry (O(N log N), on the CPU)."""
        _checks.check_geometry(self.means, self.log_scales, self.rotations)
        nodes, order = native().build_bvh(self.means.detach(), self.log_scales.detach(),
                                          self.rotations.detach(), self._kappa(), self.leaf_size)
        self.nodes, self.prim_order = nodes.to(self.device), order.to(self.device)
        self._key = self._geometry_key()
        self.refits_since_build = 0
        return self

    def refit(self) -> "GaussianScene":
        """Recompute the node bounds for moved Gaussians, keeping the tree (O(N))."""
        if self.means.shape[0] != self.prim_order.shape[0]:
            return self.rebuild()
        _checks.check_geometry(self.means, self.log_scales, self.rotations)
        self.nodes = native().refit_bvh(self.nodes, self.prim_order, self.means.detach(),
                                        self.log_scales.detach(), self.rotations.detach(),
                                        self._kappa()).to(self.device)
        self._key = self._geometry_key()
        self.refits_since_build += 1
        return self

    def update(self, *, means=None, log_scales=None, rotations=None, opacities=None, normals=None,
               rebuild: bool = False) -> "GaussianScene":
        """Swap in new tensors (same N unless rebuild=True) and refit or rebuild the BVH."""
        if opacities is not None:
            _checks.check_opacities(opacities, opacities.shape[0] if opacities.dim() else -1)
            self.opacities = opacities
        if normals is not None:
            self.normals = normals
        self.means = self.means if means is None else means
        self.log_scales = self.log_scales if log_scales is None else log_scales
        self.rotations = self.rotations if rotations is None else rotations
        return self.rebuild() if rebuild else self.refit()

    def ensure_bvh(self, alpha_min: float) -> None:
        """Refit when the geometry changed since the last build/refit, or when a trace asks for a
        smaller alpha_min than the bounds cover."""
        if alpha_min < self.bvh_alpha_min:
            self.bvh_alpha_min = float(alpha_min)
            self.refit()
        elif self._geometry_key() != self._key:
            self.refit()

    def __repr__(self) -> str:
        return (f"GaussianScene(n={self.num_gaussians}, nodes={int(self.nodes.shape[0])}, "
                f"dtype={self.dtype}, device={self.device}, alpha_min={self.bvh_alpha_min:.3g})")
