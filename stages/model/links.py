"""From artifacts to renderer inputs: frozen geometry, links, antennas, input checks.

Shared by rf-fit and predict so that both see the scene and the links the same way.
"""
from __future__ import annotations

import numpy as np
import torch

from rfir_core.errors import InputFileError, StageError

from rfir_stages.model.antenna_patterns import AntennaPattern
from rfir_stages.model.occlusion import FrozenGeometry
from rfir_stages.model.link_set import LinkSet


def geometry_from_artifact(art) -> FrozenGeometry:
    """FrozenGeometry (float64 torch) from a `scene` or `rf` artifact."""
    t = lambda k: torch.as_tensor(np.asarray(art[f"gaussians/{k}"], dtype=np.float64))  # noqa: E731
    normals = t("normals")
    normals = normals / normals.norm(dim=-1, keepdim=True).clamp(min=1e-12)
    return FrozenGeometry(t("means"), t("log_scales"), t("rotations"), normals)


def scene_centre(geom: FrozenGeometry) -> torch.Tensor:
    """Centre of the Gaussians' bounding box [3] m (the turntable axis point for RCS)."""
    return 0.5 * (geom.means.min(0).values + geom.means.max(0).values)


def antenna_axes(tx_m: torch.Tensor, rx_m: torch.Tensor, centre: torch.Tensor, task: str):
    """Antenna axes [M, 3]: boresight at the scene centre for rcs/wideband (as simulate does),
    +z (dipole axis, irrelevant for isotropic) otherwise."""
    if task in ("rcs", "wideband"):
        mid = 0.5 * (tx_m + rx_m)
        bore = centre[None] - mid
        bore = bore / bore.norm(dim=-1, keepdim=True).clamp(min=1e-12)
        return bore, bore
    z = torch.zeros_like(tx_m)
    z[:, 2] = 1.0
    return z, z


def make_links(tx_m, rx_m, freq_hz, centre: torch.Tensor, task: str) -> LinkSet:
    tx = torch.as_tensor(np.asarray(tx_m, dtype=np.float64))
    rx = torch.as_tensor(np.asarray(rx_m, dtype=np.float64))
    tx_axis, rx_axis = antenna_axes(tx, rx, centre, task)
    return LinkSet(tx, rx, torch.as_tensor(np.asarray(freq_hz, dtype=np.float64)), tx_axis, rx_axis)


def _reach2(geom: FrozenGeometry) -> torch.Tensor:
    """[G] m^2: the squared reach of each Gaussian in its plane (twice its largest scale)."""
    return (2.0 * torch.exp(geom.log_scales).max(-1).values) ** 2


def _enclosed(geom: FrozenGeometry, pts: torch.Tensor) -> torch.Tensor:
    """[P] bool: along all six axis directions the first surfel met faces away from the point,
    i.e. the point is inside a closed surface whose normals point outward (a room's walls face
    into the room, so antennas inside a room are not 'inside')."""
    means, normals = geom.means, geom.normals
    reach2 = _reach2(geom)
    inside = torch.ones(len(pts), dtype=torch.bool)
    diff = means[None] - pts[:, None]                                         # [P, G, 3]
    sq = diff * diff
    for k in range(3):
        # along +-e_k: t = +-diff_k, and the squared distance off the line is the other two components
        near_line = sq[..., (k + 1) % 3] + sq[..., (k + 2) % 3] < reach2[None]
        for sign in (1.0, -1.0):
            t = sign * diff[..., k]
            t_hit = torch.where((t > 0) & near_line, t, torch.full_like(t, float("inf")))
            first = t_hit.argmin(1)
            any_hit = torch.isfinite(t_hit.min(1).values)
            away = sign * normals[first, k] > 0                                # the first surfel faces away
            inside &= any_hit & away
    return inside


def _surface_distance(geom: FrozenGeometry, pts: torch.Tensor) -> torch.Tensor:
    """[P] m: each point's distance to the nearest Gaussian's disc (its offset along the normal where the
    point lies within the Gaussian's reach in its plane, its distance to the mean elsewhere): a point
    on a wall between two Gaussians' means is on the wall."""
    means, normals = geom.means, geom.normals
    reach2 = _reach2(geom)
    out = []
    for i in range(0, len(pts), 128):
        diff = pts[i:i + 128, None] - means[None]                              # [p, G, 3]
        off = (diff * normals[None]).sum(-1).abs()
        d2 = (diff * diff).sum(-1)
        on_disc = d2 - off * off < reach2[None]
        out.append(torch.where(on_disc, off, d2.sqrt()).min(1).values)
    return torch.cat(out) if out else torch.zeros(0, dtype=pts.dtype)


def positions_inside(geom: FrozenGeometry, points_m: np.ndarray, min_clearance_m: float) -> tuple[np.ndarray, np.ndarray]:
    """([N] bool, [N] m) for points_m [N, 3] m: the point lies inside the geometry (closer than
    min_clearance_m to a Gaussian's disc, see _surface_distance, or enclosed by outward-facing surfels,
    see _enclosed), and its distance to the nearest Gaussian's disc."""
    means = geom.means
    pts = torch.as_tensor(np.asarray(points_m, dtype=np.float64))
    uniq, inverse = torch.unique(pts, dim=0, return_inverse=True)
    nearest = _surface_distance(geom, uniq)
    inside = nearest < min_clearance_m
    # a point beyond every mean along some axis meets nothing that way, so it cannot be enclosed
    lo, hi = means.min(0).values, means.max(0).values
    cand = (((uniq >= lo) & (uniq <= hi)).all(-1) & ~inside).nonzero()[:, 0]
    step = max(1, 2_000_000 // max(geom.num, 1))
    for i in range(0, len(cand), step):
        inside[cand[i:i + step]] = _enclosed(geom, uniq[cand[i:i + step]])
    return inside[inverse].numpy(), nearest[inverse].numpy()


def inside_words(points_m: np.ndarray, inside: np.ndarray, nearest_m: np.ndarray, min_clearance_m: float) -> str:
    """'N antenna position(s) lie inside the geometry (e.g. ...)' for the points flagged by positions_inside."""
    pts = np.asarray(points_m, np.float64)
    uniq = np.unique(pts[inside], axis=0)
    i = int(np.flatnonzero(inside)[0])
    why = (f"{nearest_m[i] * 100:.1f} cm from a Gaussian's surface; need >= {min_clearance_m * 100:.0f} cm"
           if nearest_m[i] < min_clearance_m else "enclosed by the object's surface")
    return f"{len(uniq)} antenna position(s) lie inside the geometry (e.g. {np.round(pts[i], 3).tolist()} m, {why})"


def check_positions(geom: FrozenGeometry, points_m: np.ndarray, where: str, min_clearance_m: float) -> None:
    """Refuse antennas inside the geometry (positions_inside)."""
    inside, nearest = positions_inside(geom, points_m, min_clearance_m)
    if inside.any():
        raise InputFileError(inside_words(points_m, inside, nearest, min_clearance_m), path=where)


def check_overlap(geom: FrozenGeometry, meas, where: str) -> None:
    """Refuse a measurement file whose scene bounds do not overlap the Gaussians (another scene)."""
    bounds = meas.get("scene_bounds")
    if bounds is None:
        return
    lo, hi = geom.means.min(0).values.numpy(), geom.means.max(0).values.numpy()
    b_lo, b_hi = np.asarray(bounds[0]), np.asarray(bounds[1])
    slack = 0.05 * max(float(np.max(hi - lo)), 1e-3)
    inter = np.minimum(hi, b_hi) - np.maximum(lo, b_lo)
    if np.any(inter < -slack):
        raise InputFileError(f"the measurements' scene bounds {np.round(b_lo, 2).tolist()}..{np.round(b_hi, 2).tolist()} "
                             f"m do not overlap the Gaussians ({np.round(lo, 2).tolist()}..{np.round(hi, 2).tolist()} m):"
                             f" measurements of another scene?", path=where)


def pick_rows(split: np.ndarray | None, which: int, where: str) -> np.ndarray:
    """Row indices with split == which (0 train, 1 test); clear error when there are none."""
    if split is None:
        raise StageError("the measurements have no 'split' (0 train, 1 test); add one", path=where)
    rows = np.flatnonzero(np.asarray(split) == which)
    if rows.size == 0:
        name = {0: "training", 1: "test"}[which]
        raise StageError(f"empty {name} split: no row has split == {which}", path=where)
    return rows


def pick_freqs(available: np.ndarray, wanted: list | None, where: str) -> np.ndarray:
    """Column indices of the wanted frequencies (all when none given)."""
    available = np.asarray(available, dtype=np.float64)
    if not wanted:
        return np.arange(len(available))
    cols = []
    for f in wanted:
        hit = np.flatnonzero(np.abs(available - float(f)) <= 1e-6 * float(f))
        if hit.size == 0:
            raise StageError(f"frequency {float(f) / 1e9:g} GHz is not in the file "
                             f"({', '.join(f'{x / 1e9:g}' for x in available[:8])} GHz)", path=where)
        cols.append(int(hit[0]))
    return np.asarray(cols)


def radar_links(aspects_rad: np.ndarray, ranges_m: np.ndarray, centre: np.ndarray, separation_m: float = 0.002):
    """Monostatic turntable links in simulate's convention (radar at azimuth -theta, range r, at the
    centre's height; Tx separation/2 above, Rx below). Rows range-major.
    Returns (tx [L, 3], rx [L, 3], aspect [L], range [L])."""
    asp = np.tile(np.asarray(aspects_rad, float), len(ranges_m))
    rng = np.repeat(np.asarray(ranges_m, float), len(aspects_rad))
    pos = np.stack([rng * np.cos(-asp), rng * np.sin(-asp), np.zeros_like(asp)], 1) + centre
    off = np.array([0.0, 0.0, separation_m / 2])
    return pos + off, pos - off, asp, rng


def describe_antenna(ant: AntennaPattern) -> dict:
    return ant.describe()
