"""When a straight leg crosses a surface: one definition for the room model's paths and for counting the objects a
link crosses.

A leg (a Tx-Rx segment, or one leg of a reflected path) crosses what the Gaussian tracer hits along it more than
LEG_MARGIN_M from either end (`segment_hits`): hits closer to an end belong to the surface the leg starts or ends
on. What is crossed is then read at two levels: the room model's planar patches (`leg_crossings`: the exact
intersection with the patch's plane must lie on the patch), and labelled objects or grouped surfaces
(rfir_stages.model.crossings.crossing_counts: the hits' summed response must reach 1).

The tracer (`provider`) is any object with ray_hits(origins [R, 3], unit directions [R, 3], t_max=[R]) -> a hit
table with query, gaussian, t_m and response (rfir_stages.model.occlusion's providers).
"""
from __future__ import annotations

import numpy as np
import torch

LEG_MARGIN_M = 0.02   # m: hits this close to a leg's ends belong to the surfaces it starts or ends on


def segment_hits(provider, start, end, margin_m: float = LEG_MARGIN_M):
    """Tracer hits along the segments start -> end [N, 3] m, more than margin_m from either end.

    Returns numpy (leg [H] int64, gaussian [H] int64, distance from start t_m [H] m, response [H]), in the
    provider's order (by leg, then along it)."""
    a = torch.as_tensor(np.asarray(start, dtype=np.float64))
    d = torch.as_tensor(np.asarray(end, dtype=np.float64)) - a
    length = d.norm(dim=-1).clamp(min=1e-12)
    # the rays end margin_m before the far end (t_max); the hits within margin_m of the start are dropped here
    hits = provider.ray_hits(a.contiguous(), (d / length[:, None]).contiguous(), t_max=length - margin_m)
    keep = hits.t_m > margin_m
    return (hits.query[keep].numpy(), hits.gaussian[keep].numpy(), hits.t_m[keep].numpy(),
            hits.response[keep].numpy())


def leg_crossings(provider, patches, start: np.ndarray, end: np.ndarray, skip_a: np.ndarray,
                  skip_b: np.ndarray, chunk: int = 500_000):
    """Planar patches crossed by the legs start -> end [N, 3] m, not counting patches skip_a / skip_b [N] (-1: none).

    patches: the room model's PatchSet (surfel_patch [G] patch of each Gaussian or -1, num, normal [P, 3], point
    [P, 3], contains(pid, points)). Returns (leg [C], patch [C], fraction along the leg [C]). Candidates are the
    patches of the Gaussians `segment_hits` finds; a crossing counts when the exact intersection with the patch's
    plane lies on the patch."""
    legs, pids, fracs = [], [], []
    for lo in range(0, len(start), chunk):
        hi = min(len(start), lo + chunk)
        a, b = start[lo:hi], end[lo:hi]
        d = b - a
        q, g, _, _ = segment_hits(provider, a, b)
        p = patches.surfel_patch[g]
        keep = (p >= 0) & (p != skip_a[lo:hi][q]) & (p != skip_b[lo:hi][q])
        # distinct (leg, patch) pairs, by leg then patch: one crossing per surface however many surfels tile it
        # (a leg's hits come in order along it, so most repeats are neighbours: dropped first, cheaply; then
        # sorted, np.unique's hashing being many times slower here)
        pair = _drop_repeats(np.sort(_drop_repeats(q[keep] * patches.num + p[keep])))
        if len(pair) == 0:
            continue
        q, p = pair // patches.num, pair % patches.num
        n, o = patches.normal[p], patches.point[p]
        da = _dot(a[q] - o, n)
        db = _dot(b[q] - o, n)
        cross = da * db < 0
        f = da / np.where(cross, da - db, 1.0)
        x = a[q] + f[:, None] * d[q]
        cross &= patches.contains(p, x)
        legs.append(q[cross] + lo)
        pids.append(p[cross])
        fracs.append(f[cross])
    if not legs:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0)
    return np.concatenate(legs), np.concatenate(pids), np.concatenate(fracs)


def _drop_repeats(a: np.ndarray) -> np.ndarray:
    """a [N] without the entries equal to the one before them."""
    first = np.ones(len(a), dtype=bool)
    first[1:] = a[1:] != a[:-1]
    return a[first]


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of [..., 3] arrays (written out: several times faster than a sum over the last axis)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]
