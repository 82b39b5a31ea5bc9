"""Occlusion providers: who lies in front of whom, traced once while the geometry is frozen.

A provider answers two geometric questions with hit tables (no RF opacities involved; every
Gaussian is traced with opacity 1 and t_stop 0, so the table is the superset of hits for any RF
opacities a <= 1, since alpha = a G <= G):
- `segment_hits(origins [Q, 3], target_ids [Q])`: Gaussians on the segment from each origin to the
  target Gaussian's mean (the target itself excluded), for V (docs/physics.md section 4.1);
- `ray_hits(origins [R, 3], directions [R, 3] unit)`: every Gaussian along each ray, for the
  receiver grid of step 3.
The renderer turns the tables into differentiable transmittances with the RF opacities.

Implementations: `BruteForceOcclusion` (pure torch, every query against every Gaussian: the
oracle, fine for a few thousand Gaussians and small query counts) and `TracerOcclusion`
(rfir_tracer's BVH, C++/OpenMP or CUDA).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import torch

from rfir_cli.physics.gaussian_rf import quaternion_to_matrix


@dataclass(frozen=True)
class HitTable:
    """Hits sorted by query, then by distance along it (front to back).

    query [H] int64 (query index), gaussian [H] int64, t_m [H] distance from the origin [m],
    response [H] G in (0, 1] at the hit (without opacity). num_queries: Q.
    """

    query: torch.Tensor
    gaussian: torch.Tensor
    t_m: torch.Tensor
    response: torch.Tensor
    num_queries: int

    def select(self, keep: torch.Tensor) -> "HitTable":
        """Keep the hits where `keep` [H] bool is true (order preserved)."""
        return HitTable(self.query[keep], self.gaussian[keep], self.t_m[keep], self.response[keep], self.num_queries)

    @staticmethod
    def concat(tables: list["HitTable"]) -> "HitTable":
        """Stack tables whose queries follow one another."""
        off, parts = 0, []
        for t in tables:
            parts.append((t.query + off, t.gaussian, t.t_m, t.response))
            off += t.num_queries
        if not parts:
            e = torch.zeros(0, dtype=torch.int64)
            return HitTable(e, e, e.double(), e.double(), 0)
        return HitTable(*(torch.cat([p[i] for p in parts]) for i in range(4)), off)


class OcclusionProvider(Protocol):
    name: str

    def segment_hits(self, origins: torch.Tensor, target_ids: torch.Tensor) -> HitTable: ...

    def ray_hits(self, origins: torch.Tensor, directions: torch.Tensor, opacity: torch.Tensor | None = None,
                 t_stop: float = 0.0) -> HitTable: ...

    def segment_transmittance(self, origins: torch.Tensor, target_ids: torch.Tensor, margin_m: float,
                              opacity: torch.Tensor, t_stop: float = 1e-4) -> torch.Tensor: ...

    def footprint_sums(self, origins: torch.Tensor, directions: torch.Tensor, group_offsets: torch.Tensor,
                       ray_weight: torch.Tensor, opacity: torch.Tensor, t_stop: float,
                       margin_m: float) -> tuple[torch.Tensor, torch.Tensor]: ...


def transmittance_before_from_table(hits: HitTable, opacity: torch.Tensor, margin_m: float,
                                    alpha_max: float = 0.99) -> torch.Tensor:
    """[H]: per hit, prod of (1 - min(a G, alpha_max)) over its query's hits with t < t_hit - margin_m."""
    n = hits.query.numel()
    if n == 0:
        return torch.zeros(0, dtype=torch.float64)
    idx = torch.arange(n)
    new_query = torch.ones(n, dtype=torch.bool)
    new_query[1:] = hits.query[1:] != hits.query[:-1]
    first = torch.cummax(torch.where(new_query, idx, torch.zeros_like(idx)), 0).values
    key = hits.query.double() * (float(hits.t_m.max()) + margin_m + 1.0) + hits.t_m
    j = torch.maximum(torch.searchsorted(key, key - margin_m), first)
    log1m = torch.log1p(-(opacity.double()[hits.gaussian] * hits.response).clamp(max=alpha_max))
    excl = torch.cumsum(log1m, 0) - log1m
    return torch.exp(excl[j] - excl[first])


def product_from_hits(hits: HitTable, opacity: torch.Tensor) -> torch.Tensor:
    """Transmittance [Q] = prod over each query's hits of (1 - min(a G, 0.99))."""
    log1m = torch.log1p(-(opacity[hits.gaussian] * hits.response).clamp(max=0.99))
    return torch.exp(torch.zeros(hits.num_queries, dtype=log1m.dtype).index_add(0, hits.query, log1m))


@dataclass
class FrozenGeometry:
    """The frozen Gaussians: means [G, 3] m, log_scales [G, 3], rotations [G, 4] wxyz, normals [G, 3]."""

    means: torch.Tensor
    log_scales: torch.Tensor
    rotations: torch.Tensor
    normals: torch.Tensor

    @property
    def num(self) -> int:
        return int(self.means.shape[0])

    def inverse_covariance(self) -> torch.Tensor:
        """Sigma^-1 = R S^-2 R^T [G, 3, 3] in m^-2."""
        rot = quaternion_to_matrix(self.rotations)
        scaled = rot * torch.exp(-self.log_scales)[..., None, :]
        return scaled @ scaled.transpose(-1, -2)


class BruteForceOcclusion:
    """Every query against every Gaussian, in chunks (pure torch, float64)."""

    name = "brute-force"

    def __init__(self, geom: FrozenGeometry, alpha_min: float = 1e-3, chunk_pairs: int = 4_000_000):
        self.geom, self.alpha_min, self.chunk_pairs = geom, float(alpha_min), int(chunk_pairs)
        self.inv = geom.inverse_covariance()
        kappa = math.sqrt(2.0 * math.log(1.0 / self.alpha_min)) * 1.001
        self.radius = kappa * torch.exp(geom.log_scales).max(-1).values   # [G] m

    def _hits(self, o: torch.Tensor, d: torch.Tensor, t_max: torch.Tensor, exclude: torch.Tensor | None,
              first: int) -> tuple:
        """Rays o + t d (d not necessarily unit) against all Gaussians; keep 0 < t* < t_max.

        Pairs are culled first with each Gaussian's bounding sphere (the radius where
        G >= alpha_min can hold), then evaluated exactly."""
        mu = self.geom.means
        diff = mu[None] - o[:, None]                                  # [Q, G, 3]
        dd = (d * d).sum(-1)                                          # [Q]
        tp = (diff * d[:, None]).sum(-1) / dd[:, None]                # projection parameter
        perp = diff - tp[..., None] * d[:, None]
        rad = self.radius[None]
        slack = rad / dd.sqrt()[:, None]
        cand = ((perp * perp).sum(-1) <= rad**2) & (tp > -slack) & (tp < t_max[:, None] + slack)
        if exclude is not None:
            cand &= torch.arange(mu.shape[0])[None] != exclude[:, None]
        q, g = cand.nonzero(as_tuple=True)
        dq, mq, inv = d[q], diff[q, g], self.inv[g]
        sd = torch.einsum("hij,hj->hi", inv, dq)
        dsd = (sd * dq).sum(-1)
        dsm = (sd * mq).sum(-1)
        msm = torch.einsum("hi,hij,hj->h", mq, inv, mq)
        t = dsm / dsd
        resp = torch.exp(-0.5 * (msm - dsm * t).clamp(min=0.0))
        keep = (t > 0) & (t < t_max[q]) & (resp >= self.alpha_min)
        q, g, t, resp = q[keep], g[keep], t[keep], resp[keep]
        return q + first, g, t * dd[q].sqrt(), resp

    def _run(self, o, d, t_max, exclude) -> HitTable:
        n_q, n_g = o.shape[0], self.geom.num
        step = max(1, self.chunk_pairs // max(n_g, 1))
        parts = [self._hits(o[i:i + step], d[i:i + step], t_max[i:i + step],
                            None if exclude is None else exclude[i:i + step], i) for i in range(0, n_q, step)]
        if not parts:
            e = torch.zeros(0, dtype=torch.int64)
            return HitTable(e, e, e.double(), e.double(), n_q)
        q, g, t, r = (torch.cat([p[i] for p in parts]) for i in range(4))
        order = torch.argsort(q.double() * (t.max() + 1.0 if t.numel() else 1.0) + t, stable=True)
        return HitTable(q[order].long(), g[order].long(), t[order].double(), r[order].double(), n_q)

    def segment_hits(self, origins: torch.Tensor, target_ids: torch.Tensor) -> HitTable:
        o = origins.double()
        d = self.geom.means[target_ids] - o
        return self._run(o, d, torch.ones(len(o), dtype=torch.float64), target_ids)

    def ray_hits(self, origins: torch.Tensor, directions: torch.Tensor, opacity: torch.Tensor | None = None,
                 t_stop: float = 0.0) -> HitTable:
        """All hits (opacity and t_stop are accepted for interface parity; no early stop here)."""
        return self._run(origins.double(), directions.double(), torch.full((len(origins),), float("inf")), None)

    def segment_transmittance(self, origins, target_ids, margin_m, opacity, t_stop=1e-4) -> torch.Tensor:
        hits = self.segment_hits(origins, target_ids)
        length = (self.geom.means[target_ids[hits.query]] - origins[hits.query].double()).norm(dim=-1)
        return product_from_hits(hits.select(hits.t_m < length - margin_m), opacity)

    def footprint_sums(self, origins, directions, group_offsets, ray_weight, opacity, t_stop, margin_m) -> tuple:
        """(num, den) [M, G]: per group of rays (group_offsets [M + 1]) and Gaussian, the sums of w G T and
        of w G over its hits (every hit: no early stop here), T the transmittance in front with `opacity`
        ignoring the last margin_m, w = ray_weight [R]."""
        hits = self.ray_hits(origins, directions)
        m, g = group_offsets.shape[0] - 1, self.geom.num
        group = torch.searchsorted(group_offsets, hits.query, right=True) - 1
        cell = group * g + hits.gaussian
        wg = ray_weight.double()[hits.query] * hits.response
        t_before = transmittance_before_from_table(hits, opacity, margin_m)
        den = torch.zeros(m * g, dtype=torch.float64).index_add_(0, cell, wg)
        num = torch.zeros(m * g, dtype=torch.float64).index_add_(0, cell, wg * t_before)
        return num.reshape(m, g), den.reshape(m, g)


class TracerOcclusion:
    """rfir_tracer's BVH (transmittance_to_points for segments, trace for rays)."""

    name = "rfir_tracer"

    def __init__(self, geom: FrozenGeometry, alpha_min: float = 1e-3, chunk: int = 2_000_000):
        import rfir_tracer

        self._rt = rfir_tracer
        self.alpha_min, self.chunk = float(alpha_min), int(chunk)
        self.geom = geom
        self.scene = rfir_tracer.GaussianScene(geom.means.double().contiguous(), geom.log_scales.double().contiguous(),
                                               geom.rotations.double().contiguous(),
                                               normals=geom.normals.double().contiguous())

    @staticmethod
    def _table(res, first: int, scale: torch.Tensor | None) -> tuple:
        h = res.hits
        q = h.ray_ids().long()
        t = h.t.double()
        if scale is not None:
            t = t * scale[q]
        return q + first, h.gaussian_ids.long(), t, h.response.double()

    def _chunks(self, n: int, fn) -> HitTable:
        parts = [fn(i, min(n, i + self.chunk)) for i in range(0, n, self.chunk)]
        if not parts:
            e = torch.zeros(0, dtype=torch.int64)
            return HitTable(e, e, e.double(), e.double(), n)
        return HitTable(*(torch.cat([p[i] for p in parts]) for i in range(4)), n)

    def segment_hits(self, origins: torch.Tensor, target_ids: torch.Tensor) -> HitTable:
        def part(a, b):
            o = origins[a:b].double().contiguous()
            ids = target_ids[a:b]
            res = self._rt.transmittance_to_points(self.scene, o, ids, alpha_min=self.alpha_min, t_stop=0.0,
                                                   return_hits=True)
            length = (self.geom.means[ids].double() - o).norm(dim=-1)   # segment units -> metres
            return self._table(res, a, length)
        with torch.no_grad():
            return self._chunks(len(target_ids), part)

    def ray_hits(self, origins: torch.Tensor, directions: torch.Tensor, opacity: torch.Tensor | None = None,
                 t_stop: float = 0.0) -> HitTable:
        """Hits along rays; with `opacity` [G] and t_stop > 0 the list ends where T < t_stop."""
        op = None if opacity is None else opacity.double().contiguous()

        def part(a, b):
            res = self._rt.trace(self.scene, origins[a:b].double().contiguous(), directions[a:b].double().contiguous(),
                                 opacities=op, alpha_min=self.alpha_min, t_stop=t_stop if op is not None else 0.0,
                                 return_hits=True)
            return self._table(res, a, None)
        with torch.no_grad():
            return self._chunks(len(directions), part)

    def segment_transmittance(self, origins, target_ids, margin_m, opacity, t_stop=1e-4) -> torch.Tensor:
        """V [Q] from origins to the targets' means, ignoring the last margin_m before each target."""
        out = torch.empty(len(target_ids), dtype=torch.float64)
        op = opacity.double().contiguous()
        with torch.no_grad():
            for a in range(0, len(target_ids), self.chunk):
                b = min(len(target_ids), a + self.chunk)
                o = origins[a:b].double().contiguous()
                ids = target_ids[a:b].long()
                d = (self.geom.means[ids].double() - o)
                length = d.norm(dim=-1).clamp(min=1e-12)
                t_max = (1.0 - margin_m / length).clamp(min=0.0)
                out[a:b] = self._rt.trace_transmittance(self.scene, o, d.contiguous(), opacities=op, t_min=0.0,
                                                        t_max=t_max, alpha_min=self.alpha_min, t_stop=t_stop,
                                                        exclude=ids)
        return out

    def footprint_sums(self, origins, directions, group_offsets, ray_weight, opacity, t_stop, margin_m) -> tuple:
        """(num, den) [M, G] as BruteForceOcclusion.footprint_sums, each ray's hits ending where its
        transmittance falls below t_stop; traced in chunks of whole groups, summed in C++."""
        op = opacity.double().contiguous()
        m = group_offsets.shape[0] - 1
        nums, dens = [], []
        with torch.no_grad():
            k = 0
            while k < m:
                a = int(group_offsets[k])
                # as many whole groups as fit in one chunk of rays (at least one)
                k_end = max(k + 1, int(torch.searchsorted(group_offsets, a + self.chunk, right=True)) - 1)
                k_end = min(k_end, m)
                b = int(group_offsets[k_end])
                res = self._rt.trace(self.scene, origins[a:b].double().contiguous(), directions[a:b].double().contiguous(),
                                     opacities=op, alpha_min=self.alpha_min, t_stop=t_stop, return_hits=True)
                num, den = res.hits.footprint_sums(op, group_offsets[k:k_end + 1] - a, ray_weight[a:b].double(),
                                                   margin_m)
                nums.append(num)
                dens.append(den)
                k = k_end
        if not nums:
            e = torch.zeros(0, self.geom.num, dtype=torch.float64)
            return e, e.clone()
        return torch.cat(nums), torch.cat(dens)


def make_provider(kind: str, geom: FrozenGeometry, alpha_min: float = 1e-3) -> OcclusionProvider:
    """kind "auto" (the tracer when importable, else brute force), "tracer" or "brute-force"."""
    if kind in ("auto", "tracer"):
        try:
            provider = TracerOcclusion(geom, alpha_min)
            provider.segment_hits(geom.means[:1] + 1.0, torch.zeros(1, dtype=torch.int64))  # smoke test
            return provider
        except Exception:  # noqa: BLE001 - a tracer that is missing or mid-rebuild: use the oracle
            if kind == "tracer":
                raise
    return BruteForceOcclusion(geom, alpha_min)
