"""Radio insets: the part of a large surface whose radio material differs from the rest of it, found where the
training links' residuals gather on it (docs/physics.md 8.10).

Photos show a surface's look, not what it is made of: a metal whiteboard painted like the wall it hangs on, a
steel door among plaster, a sheet of metal behind paint. Such a part reflects unlike its surface, and the links
whose first-order reflection lands on it are then predicted worse than the others reflecting off the same
surface. Here each large patch's first-order reflection points (image method: the link's transmitter mirrored
in the patch's plane, joined to its receiver) are binned into square cells of `cell_m` in the patch's own axes;
a cell is marked where the mean |residual| of the links reflecting there (each weighted by the reflection's
amplitude relative to the direct path's, D / L) exceeds the patch's median cell by `z` standard errors and by
the factor `ratio`. The marked cells' connected groups of at least `min_area_m2` are the candidates, their
bounding rectangles the insets' extents. Whether an inset is kept is decided by the fit on held-out training
links (rf_fit.radio_inset_stage), so a cell marked by chance costs a fit, not a result.

A part of a surface need not lie in its plane, and photos place a plane to a centimetre or few: a board hangs a
centimetre or two in front of its wall, and at 12.5 cm wavelength a reflection's phase turns by 4 pi d cos(theta) /
lambda for a depth d (a quarter turn at 1.6 cm). `shift_lengths` moves patches by d along their normals without
tracing again: by Fermat's principle a path's length changes, to first order in d, by 2 d cos(theta) at each of
its reflections off them.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch
from scipy import ndimage

CELL_M = 0.5              # residual cells on a surface [m]: a few per whiteboard, many links per cell
MIN_PATCH_AREA_M2 = 4.0   # surfaces searched: those large enough to hold a candidate and its surround
MIN_CELL_LINKS = 20       # a cell's mean |residual| is judged on at least this many reflections
Z_MARK = 3.0              # standard errors over the median cell for a cell to be marked (a chance cell once
                          # in ~700; a candidate that no starting material or depth helps is dropped by the search)
RATIO_MARK = 1.15         # and at least this factor over it
Z_GROW, RATIO_GROW = 2.0, 1.05   # a strip along a candidate's side joins it at this excess (pooled over the strip)
EDGE_STEP_M = 0.1       # an edge's position is searched in steps of this, within a cell of the cells' edge
MIN_AREA_M2 = 1.0         # a candidate's marked cells cover at least this area
MAX_CANDIDATES = 2        # the candidates with the largest excess kept (each costs a fit)
PLANE_TOL_M = 0.05        # an inset holds the surfels this close to its surface's plane (photo planes scatter ~2 cm)


@dataclass
class InsetCandidate:
    """A candidate radio inset: patch index, the rectangle [u0, u1, v0, v1] m in the patch's (u, v) axes about
    its point, the excess sum n (mean |r| - median) over its marked cells [dB links], the marked cells' count, and
    `toward` [3]: the unit normal on the side the links reflect from (into the room)."""

    patch: int
    rect: np.ndarray
    excess: float
    cells: int
    toward: np.ndarray

    def area_m2(self) -> float:
        return float((self.rect[1] - self.rect[0]) * (self.rect[3] - self.rect[2]))


def toward_side(normal: np.ndarray, point: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """normal [3] of the plane through point [3] turned toward the side most of pts [M, 3] lie on (into the room)."""
    return normal if np.median((pts - point) @ normal) >= 0 else -normal


def reflection_points(tx_m: np.ndarray, rx_m: np.ndarray, normal: np.ndarray, point: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """First-order specular reflection of links tx_m, rx_m [M, 3] m off the plane (normal [3], point [3]):
    (hit points [M, 3] m, valid [M] bool: both ends on the same side, off the plane, weight [M]: D / L, the
    reflected amplitude's free-space share relative to the direct path's)."""
    dt, dr = (tx_m - point) @ normal, (rx_m - point) @ normal
    image = tx_m - 2.0 * dt[:, None] * normal
    valid = (dt * dr > 0) & (np.abs(dt) > 1e-6) & (np.abs(dr) > 1e-6)
    t = np.where(valid, dt / np.where(valid, dt + dr, 1.0), 0.0)            # image -> rx crosses at t
    hit = image + t[:, None] * (rx_m - image)
    length = np.linalg.norm(rx_m - image, axis=1)
    direct = np.linalg.norm(rx_m - tx_m, axis=1)
    return hit, valid, direct / np.maximum(length, 1e-9)


def find_candidates(tx_m: np.ndarray, rx_m: np.ndarray, residual_db: np.ndarray, patches, surfel_means: np.ndarray,
                    cell_m: float = CELL_M, min_patch_area_m2: float = MIN_PATCH_AREA_M2) -> list[InsetCandidate]:
    """Candidate radio insets (module docstring) from links tx_m, rx_m [M, 3] m with residuals residual_db [M]
    (measured - predicted), on the patches (room_paths.PatchSet) of at least min_patch_area_m2; surfel_means
    [G, 3] m: the surfels' centres (a patch's extent: its surfels' (u, v) range). The baseline is the median cell
    over all those surfaces (a board may take most of its wall's reflections); marked cells a cell apart are
    joined (morphological closing). Largest excess first."""
    absr = np.abs(np.asarray(residual_db, np.float64))
    spread = float(absr.std()) if len(absr) > 1 else 0.0
    grids = []
    for p in np.flatnonzero(patches.area >= min_patch_area_m2):
        n, o, u, v = patches.normal[p], patches.point[p], patches.u[p], patches.v[p]
        rel = surfel_means[patches.surfel_patch == p] - o
        su, sv = rel @ u, rel @ v
        lo, hi = np.array([su.min(), sv.min()]), np.array([su.max(), sv.max()])
        shape = np.maximum(np.ceil((hi - lo) / cell_m).astype(int), 1)
        hit, valid, w = reflection_points(tx_m, rx_m, n, o)
        toward = toward_side(n, o, tx_m[valid]) if valid.any() else n
        hu, hv = (hit - o) @ u, (hit - o) @ v
        i = np.floor((hu - lo[0]) / cell_m).astype(int)
        j = np.floor((hv - lo[1]) / cell_m).astype(int)
        ok = valid & (i >= 0) & (i < shape[0]) & (j >= 0) & (j < shape[1])
        flat = i[ok] * shape[1] + j[ok]
        count = np.bincount(flat, minlength=shape.prod())
        wsum = np.bincount(flat, weights=w[ok], minlength=shape.prod())
        mean = np.bincount(flat, weights=w[ok] * absr[ok], minlength=shape.prod()) / np.maximum(wsum, 1e-300)
        w2 = np.bincount(flat, weights=w[ok] ** 2, minlength=shape.prod())
        n_eff = wsum ** 2 / np.maximum(w2, 1e-300)                       # Kish's effective count of weighted links
        grids.append((int(p), lo, shape, count >= MIN_CELL_LINKS, mean, n_eff, toward, wsum, w2,
                      np.stack([hu, hv, w, absr], 1)[ok]))
    judged = np.concatenate([g[4][g[3]] for g in grids]) if grids else np.zeros(0)
    if len(judged) < 3:
        return []
    base = float(np.median(judged))
    out = []
    for p, lo, shape, ok, mean, n_eff, toward, wsum, w2, points in grids:
        marked = ok & (mean - base > Z_MARK * spread / np.sqrt(np.maximum(n_eff, 1.0))) & (mean > RATIO_MARK * base)
        joined = ndimage.binary_closing(marked.reshape(shape), structure=np.ones((3, 3)), border_value=0) | \
            marked.reshape(shape)
        groups, num = ndimage.label(joined)
        for g in range(1, num + 1):
            cells = np.flatnonzero(groups.ravel() == g)
            if len(cells) * cell_m ** 2 < MIN_AREA_M2:
                continue
            ci, cj = cells // shape[1], cells % shape[1]
            box = _grown([ci.min(), ci.max() + 1, cj.min(), cj.max() + 1], shape, mean, wsum, w2, base, spread)
            rect = _edges(np.array([lo[0] + box[0] * cell_m, lo[0] + box[1] * cell_m,
                                    lo[1] + box[2] * cell_m, lo[1] + box[3] * cell_m]), points, base, cell_m)
            mine = cells[ok[cells]]
            excess = float(((mean[mine] - base) * n_eff[mine]).sum())
            out.append(InsetCandidate(p, rect, excess, int(marked[cells].sum()), toward))
    out.sort(key=lambda c: -c.excess)
    return out[:MAX_CANDIDATES]


def _grown(box: list, shape, mean: np.ndarray, wsum: np.ndarray, w2: np.ndarray, base: float, spread: float) -> list:
    """box [i0, i1, j0, j1) of cells, grown a row or column at a time while the strip along a side, pooled, exceeds
    the baseline by Z_GROW standard errors and RATIO_GROW: a part's edge cells, partly on it, fall below the marking
    threshold but not below this one."""
    grid = lambda a: a.reshape(shape)  # noqa: E731
    m, w, q = grid(mean * wsum), grid(wsum), grid(w2)
    while True:
        grown = False
        for side in range(4):
            i0, i1, j0, j1 = box
            strip = {0: (slice(i0 - 1, i0), slice(j0, j1)), 1: (slice(i1, i1 + 1), slice(j0, j1)),
                     2: (slice(i0, i1), slice(j0 - 1, j0)), 3: (slice(i0, i1), slice(j1, j1 + 1))}[side]
            if box[side] == (0 if side in (0, 2) else shape[side // 2]):
                continue
            sw, sq = w[strip].sum(), q[strip].sum()
            if sw <= 0:
                continue
            pooled, n_eff = m[strip].sum() / sw, sw ** 2 / max(sq, 1e-300)
            if pooled - base > Z_GROW * spread / np.sqrt(max(n_eff, 1.0)) and pooled > RATIO_GROW * base:
                box[side] += -1 if side in (0, 2) else 1
                grown = True
        if not grown:
            return box


def _edges(rect: np.ndarray, points: np.ndarray, base: float, cell_m: float) -> np.ndarray:
    """The rectangle [u0, u1, v0, v1] m with each edge placed, within a cell of where the cells put it, at the step
    that best splits the reflection points (points [n, 4]: u, v, weight, |residual|) across it: a step from the
    baseline outside to the rectangle's own weighted mean |residual| inside, least squares over EDGE_STEP_M strips
    (the cells put an edge only to their own size)."""
    rect = rect.astype(float).copy()
    u, v, w, a = points.T
    for side in range(4):
        along, across = (u, v) if side < 2 else (v, u)
        lo_x, hi_x = (rect[2], rect[3]) if side < 2 else (rect[0], rect[1])
        band = (across >= lo_x) & (across <= hi_x)
        inner = band & (along >= rect[side & ~1]) & (along <= rect[side | 1])
        if w[inner].sum() <= 0:
            continue
        level = float((w[inner] * a[inner]).sum() / w[inner].sum())
        edges = rect[side] + np.arange(-cell_m, cell_m + 1e-9, EDGE_STEP_M)
        inward = 1.0 if side % 2 == 0 else -1.0          # u0 / v0 edges: the inset lies at larger values
        near = band & (np.abs(along - rect[side]) <= 2 * cell_m)
        cost = []
        for e in edges:
            inside = near & ((along - e) * inward >= 0)
            target = np.where(inside, level, base)
            cost.append(float((w[near] * (a[near] - target[near]) ** 2).sum()))
        cost = np.asarray(cost)
        ties = np.flatnonzero(cost <= cost.min() * (1 + 1e-12))     # no point between two edges: the same cost
        rect[side] = edges[ties[np.argmin(np.abs(edges[ties] - rect[side]))]]
    return rect


def inset_surfels(candidate: InsetCandidate, patches, surfel_means: np.ndarray, surfel_normals: np.ndarray,
                  plane_tol_m: float = PLANE_TOL_M) -> np.ndarray:
    """Indices of the surfels in the candidate's rectangle on its patch's plane: centres within plane_tol_m of the
    plane, normals within 25 degrees of its axis (either sense), whatever patch they are in (a part labelled apart
    in the same plane, as a board in a wall's opening, is the first thing an inset there must hold)."""
    p = candidate.patch
    rel = surfel_means - patches.point[p]
    su, sv, sn = rel @ patches.u[p], rel @ patches.v[p], rel @ patches.normal[p]
    r = candidate.rect
    near = (np.abs(sn) <= plane_tol_m) & (np.abs(surfel_normals @ patches.normal[p]) >= np.cos(np.radians(25.0)))
    return np.flatnonzero(near & (su >= r[0]) & (su <= r[1]) & (sv >= r[2]) & (sv <= r[3]))


def shift_lengths(paths, offset_of_patch: np.ndarray):
    """The paths (room_paths.RoomPaths) with each length shortened by 2 d_p cos(theta) per reflection off patch p,
    offset_of_patch [P] m: d_p, each patch moved by it toward the side the paths reflect from (first order in d_p:
    Fermat's principle). Nothing traced again."""
    d = torch.as_tensor(np.asarray(offset_of_patch, np.float64))[paths.patch.clamp(min=0)]
    delta = 2.0 * (paths.cos * d * (paths.kind == 1)).sum(1)
    return replace(paths, length_m=paths.length_m - delta)
