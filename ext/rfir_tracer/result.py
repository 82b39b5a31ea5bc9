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

    def footprint_sums(self, opacities: torch.Tensor, group_offsets: torch.Tensor, ray_weight: torch.Tensor,
                       margin: float = 0.0, alpha_max: float = 0.99) -> tuple[torch.Tensor, torch.Tensor]:
        """(num, den), each [M, N]: per group of rays and Gaussian, sum of w G and of w G T over its hits.

        The rays come in M consecutive groups (group_offsets [M + 1] int64 over the rays) with
        weights ray_weight [R] (e.g. solid angles); G is a hit's response and T the transmittance in
        front of it with `opacities` [N]: prod of (1 - min(a G, alpha_max)) over the same ray's hits
        with t < t_hit - margin. C++ on the CPU, torch elsewhere.
        """
        op = opacities.detach().to(self.t.device, self.t.dtype).contiguous()
        w = ray_weight.detach().to(self.t.device, self.t.dtype).contiguous()
        grp = group_offsets.to(self.t.device, torch.int64).contiguous()
        if self.t.device.type == "cpu":
            from ._ext import native

            num, den = native().footprint_sums(self.offsets.contiguous(), self.gaussian_ids.contiguous(),
                                               self.t.contiguous(), self.response.contiguous(), op, grp, w,
                                               float(margin), float(alpha_max))
            return num, den
        return self._footprint_sums_torch(op, grp, w, margin, alpha_max)

    def _footprint_sums_torch(self, op: torch.Tensor, grp: torch.Tensor, w: torch.Tensor, margin: float,
                              alpha_max: float) -> tuple[torch.Tensor, torch.Tensor]:
        """The same sums in torch (devices without the C++ loop; a cross-check in the tests)."""
        n = op.shape[0]
        m = grp.shape[0] - 1
        ray = self.ray_ids()
        ids = self.gaussian_ids.long()
        log1m = torch.log1p(-(op[ids] * self.response).clamp(max=alpha_max))
        excl = torch.cumsum(log1m, 0) - log1m
        key = ray.to(self.t.dtype) * (float(self.t.max()) + abs(margin) + 1.0 if self.num_hits else 1.0) + self.t
        first = self.offsets[:-1][ray]
        j = torch.maximum(torch.searchsorted(key, key - margin), first)
        t_before = torch.exp(excl[j] - excl[first])
        group = torch.searchsorted(grp, ray, right=True) - 1
        cell = group * n + ids
        wg = w[ray] * self.response
        den = torch.zeros(m * n, dtype=self.t.dtype, device=self.t.device).index_add_(0, cell, wg)
        num = torch.zeros(m * n, dtype=self.t.dtype, device=self.t.device).index_add_(0, cell, wg * t_before)
        return num.reshape(m, n), den.reshape(m, n)

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
