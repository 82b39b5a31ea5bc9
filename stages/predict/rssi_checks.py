"""Position checks and receiver grids for `predict rssi`.

`check_points` names positions outside the scene's bounds (the Gaussians' bounding box) or inside
the geometry (within a surfel's footprint and thickness: Gaussian response >= `touch_response`, or
enclosed by outward-facing surfels such as a desk leg); the caller warns, it does not refuse.
`floor_grid` makes the receiver grid of `--grid HEIGHT,STEP`.
"""
from __future__ import annotations

import numpy as np
import torch

from rfir_core.errors import ConfigError
from rfir_stages.model.links import _enclosed
from rfir_stages.model.occlusion import FrozenGeometry

MAX_NAMED = 5
CHECK_BLOCK = 4096   # points checked at a time (memory ~ CHECK_BLOCK x a few kB)


def max_response(geom: FrozenGeometry, points: np.ndarray, chunk: int = 256) -> np.ndarray:
    """[N] largest Gaussian response exp(-0.5 (x - mu)^T Sigma^-1 (x - mu)) at each point."""
    inv = geom.inverse_covariance()
    pts = torch.as_tensor(np.asarray(points, np.float64))
    out = []
    for a in range(0, len(pts), chunk):
        diff = pts[a:a + chunk, None] - geom.means[None]                # [n, G, 3]
        m = torch.einsum("ngi,gij,ngj->ng", diff, inv, diff)
        out.append(torch.exp(-0.5 * m.min(1).values))
    return torch.cat(out).numpy() if out else np.zeros(0)


def _name(points: np.ndarray, idx: np.ndarray) -> str:
    shown = ", ".join(f"({', '.join(f'{x:.2f}' for x in points[i])})" for i in idx[:MAX_NAMED])
    more = f" and {len(idx) - MAX_NAMED} more" if len(idx) > MAX_NAMED else ""
    return shown + more


def enclosed(provider, geom: FrozenGeometry, points: torch.Tensor) -> torch.Tensor:
    """[P] bool: along all six axis directions the first surfel met faces away from the point (inside a
    closed surface with outward normals; a room's walls face inward, so its inside is not 'enclosed').
    The traced version of rfir_stages.model.links._enclosed (6 rays per point through the BVH)."""
    dirs = torch.cat([torch.eye(3), -torch.eye(3)]).double()
    o = points.double().repeat_interleave(6, 0)
    d = dirs.repeat(len(points), 1)
    hits = provider.ray_hits(o.contiguous(), d.contiguous())
    n = len(o)
    first = torch.full((n,), -1, dtype=torch.int64)
    if hits.query.numel():
        new = torch.ones(hits.query.numel(), dtype=torch.bool)
        new[1:] = hits.query[1:] != hits.query[:-1]
        first[hits.query[new]] = hits.gaussian[new]
    away = torch.zeros(n, dtype=torch.bool)
    ok = first >= 0
    away[ok] = (geom.normals[first[ok]] * d[ok]).sum(-1) > 0
    return away.reshape(len(points), 6).all(1)


def check_points(geom: FrozenGeometry, points: np.ndarray, what: str, bounds, touch_response: float = 0.05,
                 provider=None) -> list[str]:
    """Warnings (one line each) for `what` positions [N, 3] m outside bounds (lo [3], hi [3]) or inside the geometry."""
    points = np.unique(np.asarray(points, np.float64), axis=0)
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    out = []
    outside = np.flatnonzero(np.any(points < lo - 1e-9, 1) | np.any(points > hi + 1e-9, 1))
    if outside.size:
        out.append(f"{outside.size} {what} position(s) outside the scene's bounds {np.round(lo, 2).tolist()}.."
                   f"{np.round(hi, 2).tolist()} m: {_name(points, outside)} (extrapolation)")
    inside_mask = np.zeros(len(points), dtype=bool)
    step = max(1, 2_000_000 // max(geom.num, 1))
    # in blocks of points: the six traced rays of each point and their hits take kilobytes a point, so a whole
    # fine grid at once would need gigabytes
    for lo in range(0, len(points), CHECK_BLOCK):
        block = points[lo:lo + CHECK_BLOCK]
        mask = max_response(geom, block) >= touch_response
        pts = torch.as_tensor(block)
        if provider is not None:
            mask |= enclosed(provider, geom, pts).numpy()
        else:
            mask |= torch.cat([_enclosed(geom, pts[i:i + step]) for i in range(0, len(pts), step)]).numpy()
        inside_mask[lo:lo + len(block)] = mask
    inside = np.flatnonzero(inside_mask)
    if inside.size:
        out.append(f"{inside.size} {what} position(s) inside walls or objects: {_name(points, inside)}")
    return out


def grid_shape(bounds, step_m: float) -> tuple[int, int]:
    """(nx, ny) cells of `floor_grid` (checked first, so a huge grid is refused before it is built)."""
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    if not step_m > 0:
        raise ConfigError(f"--grid step must be positive, got {step_m}")
    n = np.floor((hi[:2] - lo[:2]) / step_m + 1e-9).astype(int)
    if np.any(n < 1):
        raise ConfigError(f"--grid step {step_m} m is larger than the scene ({np.round(hi - lo, 2).tolist()} m)")
    return int(n[0]), int(n[1])


def floor_grid(bounds, height_m: float, step_m: float) -> np.ndarray:
    """Receiver points [N, 3] on a horizontal grid at height_m, cells of step_m inside the x-y bounds
    (cell centres, x-major)."""
    lo, hi = (np.asarray(b, np.float64) for b in bounds)
    n = grid_shape(bounds, step_m)
    xs = 0.5 * (lo[0] + hi[0]) + step_m * (np.arange(n[0]) - 0.5 * (n[0] - 1))
    ys = 0.5 * (lo[1] + hi[1]) + step_m * (np.arange(n[1]) - 0.5 * (n[1] - 1))
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, float(height_m))], 1)
