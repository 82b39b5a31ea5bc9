"""Typed results of the tracer (shared by the native tracer and the torch reference)."""
from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass(frozen=True)
class HitLists:
    """Per-ray composited hits in CSR form, front to back (ascending t*, ties by id).

    Ray ``r`` (flattened index) owns entries ``offsets[r]:offsets[r + 1]``. Only hits that were
    composited are listed (alpha >= alpha_min, t_min < t* < t_max, before transmittance fell
    below t_stop). Not differentiable: recompute responses from the ids where gradients are needed.
    """

    offsets: torch.Tensor       # [R + 1] int64
    gaussian_ids: torch.Tensor  # [H] int32
    t: torch.Tensor             # [H] t* of each hit (ray parameter; metres for unit directions)
    response: torch.Tensor      # [H] G = exp(-maha / 2) at t*, without opacity, in (0, 1]

    @property
    def num_hits(self) -> int:
        return int(self.gaussian_ids.shape[0])

    def ray_ids(self) -> torch.Tensor:
        """[H] int64: the (flattened) ray index of each hit."""
        counts = self.offsets[1:] - self.offsets[:-1]
        return torch.repeat_interleave(torch.arange(counts.shape[0], device=counts.device), counts)

    def of_ray(self, r: int):
        """(ids, t, response) of one ray."""
        a, b = int(self.offsets[r]), int(self.offsets[r + 1])
        return self.gaussian_ids[a:b], self.t[a:b], self.response[a:b]


@dataclass(frozen=True)
class TraceResult:
    """Composited outputs per ray; leading dims follow the rays' batch shape ``[...]``.

    features = sum_i w_i f_i [..., K]; depth = sum_i w_i t*_i [...] (ray parameter units, metres
    for unit directions); depth_sq = sum_i w_i t*_i^2 [...]; normal = sum_i w_i n_i [..., 3];
    transmittance = prod_i (1 - alpha_i) [...] (1 for rays that hit nothing);
    hit_count [...] int32; hits: optional CSR hit lists over the flattened rays;
    evaluations [...] int32: Gaussians whose response was evaluated (BVH candidates), a
    diagnostic of traversal cost (None from the reference).
    """

    features: torch.Tensor
    depth: torch.Tensor
    depth_sq: torch.Tensor
    normal: torch.Tensor
    transmittance: torch.Tensor
    hit_count: torch.Tensor
    hits: HitLists | None = None
    evaluations: torch.Tensor | None = None

    @property
    def opacity(self) -> torch.Tensor:
        """Accumulated alpha, 1 - transmittance [...]."""
        return 1.0 - self.transmittance
