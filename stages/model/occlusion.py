"""Occlusion providers: who lies in front of whom, traced while the geometry is frozen.

A provider answers two questions:
- `segment_transmittance(origins [Q, 3], target_ids [Q], margin_m, opacity [G])`: V, the
  transmittance from each origin to the target Gaussian's mean (the target itself and the last
  margin_m excluded), with one RF opacity per Gaussian (docs/physics.md section 4.1);
- `ray_hits(origins [R, 3], directions [R, 3] unit, t_max [R] m)`: a hit table of every Gaussian along each ray
  (traced with opacity 1 and t_stop 0: the superset of hits for any RF opacities a <= 1, since
  alpha = a G <= G), for the room model's walls and the RSSI checks.

Implementations: `BruteForceOcclusion` (pure torch, every query against every Gaussian: the
oracle, fine for a few thousand Gaussians and small query counts) and `TracerOcclusion`
(rfir_tracer's BVH, C++/OpenMP or CUDA).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

import torch

from rfir_core.physics.gaussian_rf import quaternion_to_matrix


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

class OcclusionProvider(Protocol):
    name: str

    def ray_hits(self, origins: torch.Tensor, directions: torch.Tensor, opacity: torch.Tensor | None = None,
                 t_stop: float = 0.0, t_max: torch.Tensor | None = None) -> HitTable: ...

    def segment_transmittance(self, origins: torch.Tensor, target_ids: torch.Tensor, margin_m: float,
                              opacity: torch.Tensor, t_stop: float = 1e-4) -> torch.Tensor: ...


def lit_stop(t_stop: float, lit_threshold: float) -> float:
    """The t_stop to trace with when the transmittance only decides lit (> lit_threshold) or shadowed
    (physical.lit_state): a ray can stop once below the threshold, since a product of factors in [0, 1]
    never rises again. Lit rays are traced to the end as before, shadowed ones end at their first
    opaque surface: the same lit states at a fraction of the cost (most of a solid's surfels are
    shadowed from any one antenna). lit_threshold 0 (soft shadows, the transmittance itself): t_stop."""
    return max(float(t_stop), float(lit_threshold)) if lit_threshold > 0 else float(t_stop)


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
                 t_stop: float = 0.0, t_max: torch.Tensor | None = None) -> HitTable:
        """All hits before t_max [R] m (None: all; opacity and t_stop are accepted for interface parity; no early
        stop here)."""
        t_max = torch.full((len(origins),), float("inf")) if t_max is None else t_max.double()
        return self._run(origins.double(), directions.double(), t_max, None)

    def segment_transmittance(self, origins, target_ids, margin_m, opacity, t_stop=1e-4) -> torch.Tensor:
        hits = self.segment_hits(origins, target_ids)
        length = (self.geom.means[target_ids[hits.query]] - origins[hits.query].double()).norm(dim=-1)
        return product_from_hits(hits.select(hits.t_m < length - margin_m), opacity)

class TracerOcclusion:
    """rfir_tracer's BVH (transmittance_to_points for segments, trace for rays)."""

    name = "rfir_tracer"

    def __init__(self, geom: FrozenGeometry, alpha_min: float = 1e-3, chunk: int = 2_000_000, device: str = "cpu"):
        """device: where the BVH and the traversal live ("cpu" or "cuda"); queries and answers stay on
        the CPU (they are moved), so callers do not change. float64 on both: the same answers."""
        import rfir_tracer

        self._rt = rfir_tracer
        self.alpha_min, self.chunk, self.device = float(alpha_min), int(chunk), torch.device(device)
        self.name = "rfir_tracer" if self.device.type == "cpu" else f"rfir_tracer ({self.device.type})"
        self.geom = geom
        self.scene = rfir_tracer.GaussianScene(*(t.double().to(self.device).contiguous()
                                                 for t in (geom.means, geom.log_scales, geom.rotations)),
                                               normals=geom.normals.double().to(self.device).contiguous())

    def _dev(self, t: torch.Tensor) -> torch.Tensor:
        return t.double().to(self.device).contiguous()

    @staticmethod
    def _table(res, first: int) -> tuple:
        h = res.hits
        return (h.ray_ids().long().cpu() + first, h.gaussian_ids.long().cpu(), h.t.double().cpu(),
                h.response.double().cpu())

    def _chunks(self, n: int, fn) -> HitTable:
        parts = [fn(i, min(n, i + self.chunk)) for i in range(0, n, self.chunk)]
        if not parts:
            e = torch.zeros(0, dtype=torch.int64)
            return HitTable(e, e, e.double(), e.double(), n)
        return HitTable(*(torch.cat([p[i] for p in parts]) for i in range(4)), n)

    def ray_hits(self, origins: torch.Tensor, directions: torch.Tensor, opacity: torch.Tensor | None = None,
                 t_stop: float = 0.0, t_max: torch.Tensor | None = None) -> HitTable:
        """Hits along rays before t_max [R] m (None: all); with `opacity` [G] and t_stop > 0 the list ends where
        T < t_stop."""
        op = None if opacity is None else self._dev(opacity)

        def part(a, b):
            res = self._rt.trace(self.scene, self._dev(origins[a:b]), self._dev(directions[a:b]),
                                 t_max=math.inf if t_max is None else self._dev(t_max[a:b]),
                                 opacities=op, alpha_min=self.alpha_min, t_stop=t_stop if op is not None else 0.0,
                                 return_hits=True)
            return self._table(res, a)
        with torch.no_grad():
            return self._chunks(len(directions), part)

    def segment_transmittance(self, origins, target_ids, margin_m, opacity, t_stop=1e-4) -> torch.Tensor:
        """V [Q] from origins to the targets' means, ignoring the last margin_m before each target."""
        out = torch.empty(len(target_ids), dtype=torch.float64)
        with torch.no_grad():
            for a in range(0, len(target_ids), self.chunk):
                b = min(len(target_ids), a + self.chunk)
                o, d, t_max = segment_rays(origins[a:b], self.geom.means[target_ids[a:b].long()], margin_m)
                out[a:b] = self.rays_transmittance(o, d, t_max, opacity, t_stop, target_ids[a:b].long())
        return out

    def rays_transmittance(self, o: torch.Tensor, d: torch.Tensor, t_max: torch.Tensor, opacity: torch.Tensor,
                           t_stop: float, exclude: torch.Tensor) -> torch.Tensor:
        """Transmittance [Q] along o + t d, 0 < t < t_max [Q] (float64), ignoring Gaussian exclude [Q] (-1: none)."""
        return self._rt.trace_transmittance(self.scene, self._dev(o), self._dev(d), opacities=self._dev(opacity),
                                            t_min=0.0, t_max=self._dev(t_max), alpha_min=self.alpha_min,
                                            t_stop=t_stop, exclude=exclude.to(self.device)).cpu()


def segment_rays(origins: torch.Tensor, ends: torch.Tensor, margin_m: float) -> tuple:
    """(o [Q, 3], d = ends - o [Q, 3], t_max [Q]) of segments origins -> ends [Q, 3] m with their last margin_m
    left out (t in units of the segment: t_max = 1 - margin_m / length, at least 0). float64."""
    o = origins.double().contiguous()
    d = ends.double() - o
    length = d.norm(dim=-1).clamp(min=1e-12)
    return o, d, (1.0 - margin_m / length).clamp(min=0.0)


def make_provider(kind: str, geom: FrozenGeometry, alpha_min: float = 1e-3, device: str = "cpu") -> OcclusionProvider:
    """kind "auto" (the tracer when importable, else brute force), "tracer" or "brute-force"; device:
    where the tracer runs ("cuda" needs the extension's CUDA build; the brute force is CPU only)."""
    if kind in ("auto", "tracer"):
        try:
            provider = TracerOcclusion(geom, alpha_min, device=device)
            provider.segment_transmittance(geom.means[:1] + 1.0, torch.zeros(1, dtype=torch.int64), 0.0,  # smoke test
                                           torch.ones(geom.num, dtype=torch.float64))
            return provider
        except Exception:  # noqa: BLE001 - a tracer that is missing or mid-rebuild: use the oracle
            if kind == "tracer" or torch.device(device).type != "cpu":   # a GPU asked for is not swapped silently for the CPU
                raise
    return BruteForceOcclusion(geom, alpha_min)
