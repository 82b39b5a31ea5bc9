"""Brute-force pure-torch reference tracer (the test oracle), written from docs/physics.md section 2.

Every ray is tested against every Gaussian in float64, with the literal formulas
``t* = d^T Sigma^-1 (mu - o) / (d^T Sigma^-1 d)`` and
``G = exp(-0.5 (x(t*) - mu)^T Sigma^-1 (x(t*) - mu))``, ``alpha = min(opacity G, 0.99)``,
and the same acceptance rules as the native tracer: alpha >= alpha_min, t_min < t* < t_max,
front-to-back order by (t*, id), stop after the hit that takes transmittance below t_stop.
Differentiable by torch autograd. Memory is O(rays_per_chunk x N); slow by design.
"""
from __future__ import annotations

import math

import torch

from ._checks import ALPHA_MAX
from .result import HitLists, TraceResult


def quat_to_rotmat(q: torch.Tensor) -> torch.Tensor:
    """[N, 4] wxyz (any non-zero norm) -> [N, 3, 3] rotation matrices (columns = axes)."""
    q = q / q.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(q.shape[:-1] + (3, 3))


def inverse_covariance(log_scales: torch.Tensor, rotations: torch.Tensor) -> torch.Tensor:
    """Sigma^-1 = R diag(exp(-2 log s)) R^T, [N, 3, 3]."""
    R = quat_to_rotmat(rotations)
    return R @ torch.diag_embed(torch.exp(-2.0 * log_scales)) @ R.transpose(-1, -2)


def _trace_chunk(mu, sinv, opac, feat, nrm, o, d, tmin, tmax, excl, alpha_min, t_stop):
    n = mu.shape[0]
    p = mu[None] - o[:, None]                                     # [R, N, 3]
    sd = torch.einsum("nij,rj->rni", sinv, d)                     # Sigma^-1 d
    t = (sd * p).sum(-1) / (sd * d[:, None]).sum(-1)              # [R, N]
    e = o[:, None] + t[..., None] * d[:, None] - mu[None]         # x(t*) - mu
    maha = torch.einsum("rni,nij,rnj->rn", e, sinv, e)
    G = torch.exp(-0.5 * maha)
    alpha = torch.clamp(opac[None] * G, max=ALPHA_MAX)
    valid = (alpha >= alpha_min) & (t > tmin[:, None]) & (t < tmax[:, None])
    if excl is not None:
        valid &= torch.arange(n, device=mu.device)[None] != excl[:, None]
    key = torch.where(valid, t, torch.full_like(t, math.inf)).detach()
    order = torch.sort(key, dim=1, stable=True).indices           # ties: ascending id
    a = torch.gather(alpha, 1, order)
    v = torch.gather(valid, 1, order)
    a = torch.where(v, a, torch.zeros_like(a))
    ones = torch.ones_like(a[:, :1])
    T_before = torch.cat([ones, torch.cumprod(1.0 - a, dim=1)[:, :-1]], dim=1)
    inc = v & (T_before >= t_stop)
    w = torch.where(inc, a * T_before, torch.zeros_like(a))
    ts = torch.gather(t, 1, order)
    out_f = torch.einsum("rn,rnk->rk", w, feat[order]) if feat.shape[1] else w.new_zeros(w.shape[0], 0)
    out_n = torch.einsum("rn,rnk->rk", w, nrm[order]) if nrm is not None else w.new_zeros(w.shape[0], 3)
    depth = (w * ts).sum(1)
    depth_sq = (w * ts * ts).sum(1)
    trans = torch.where(inc, 1.0 - a, torch.ones_like(a)).prod(1)
    count = inc.sum(1)
    # boolean indexing walks row-major: ray by ray, front to back within a ray
    hit_ids, hit_t, hit_g = order[inc], ts[inc], torch.gather(G, 1, order)[inc]
    return out_f, depth, depth_sq, out_n, trans, count, hit_ids, hit_t, hit_g


def trace_reference(means, log_scales, rotations, opacities, origins, directions, *,
                    features=None, normals=None, t_min=0.0, t_max=math.inf,
                    alpha_min: float = 1.0 / 255.0, t_stop: float = 1e-4, exclude=None,
                    max_pairs_per_chunk: int = 2_000_000) -> TraceResult:
    """Reference for ``rfir_tracer.trace`` on flattened rays.

    Args mirror ``trace``: means/log_scales [N, 3], rotations [N, 4] wxyz, opacities [N] in
    [0, 1], origins [R, 3] or [3], directions [R, 3], features [N, K] or None, normals [N, 3] or
    None, t_min/t_max float or [R], exclude None or [R] ids. Computation is float64; results are
    float64 and always carry hit lists (ids int32).
    """
    f64 = torch.float64
    mu, ls, q = means.to(f64), log_scales.to(f64), rotations.to(f64)
    opac = opacities.to(f64)
    n = mu.shape[0]
    feat = features.to(f64) if features is not None else mu.new_zeros(n, 0)
    nrm = normals.to(f64) if normals is not None else None
    d = directions.detach().to(f64).reshape(-1, 3)
    r = d.shape[0]
    o = torch.broadcast_to(origins.detach().to(f64), (r, 3))
    tmin = torch.broadcast_to(torch.as_tensor(t_min, dtype=f64), (r,))
    tmax = torch.broadcast_to(torch.as_tensor(t_max, dtype=f64), (r,))
    excl = None if exclude is None else torch.broadcast_to(torch.as_tensor(exclude), (r,)).long()
    sinv = inverse_covariance(ls, q)
    chunk = max(1, max_pairs_per_chunk // max(n, 1))
    parts = []
    for a in range(0, r, chunk):
        b = min(r, a + chunk)
        parts.append(_trace_chunk(mu, sinv, opac, feat, nrm, o[a:b], d[a:b], tmin[a:b], tmax[a:b],
                                  None if excl is None else excl[a:b], alpha_min, t_stop))
    if not parts:  # no rays
        z = mu.new_zeros(0)
        parts = [(mu.new_zeros(0, feat.shape[1]), z, z, mu.new_zeros(0, 3), z,
                  torch.zeros(0, dtype=torch.int64), torch.zeros(0, dtype=torch.int64), z, z)]
    cat = [torch.cat([p[i] for p in parts]) for i in range(9)]
    offsets = torch.cat([torch.zeros(1, dtype=torch.int64), torch.cumsum(cat[5].long(), 0)])
    hits = HitLists(offsets, cat[6].to(torch.int32), cat[7], cat[8])
    return TraceResult(features=cat[0], depth=cat[1], depth_sq=cat[2], normal=cat[3],
                       transmittance=cat[4], hit_count=cat[5].to(torch.int32), hits=hits)


def transmittance_reference(means, log_scales, rotations, opacities, origins, gaussian_ids, *,
                            alpha_min: float = 1.0 / 255.0, t_stop: float = 1e-4) -> TraceResult:
    """Reference for ``transmittance_to_points``: segments origin -> target mean, t in (0, 1)."""
    ids = torch.as_tensor(gaussian_ids).long()
    o = torch.broadcast_to(origins.detach().to(torch.float64), (ids.shape[0], 3))
    d = means.detach().to(torch.float64)[ids] - o
    return trace_reference(means, log_scales, rotations, opacities, o, d, t_min=0.0, t_max=1.0,
                           alpha_min=alpha_min, t_stop=t_stop, exclude=ids)
