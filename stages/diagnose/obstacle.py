"""An unmodelled obstacle: links whose direct segment crosses a region of the floor plan lose (or gain)
the same dB. The region is a box on the floor plan (x0, y0, x1, y1 [m], full height), found from the
spatially clustered residual: every box on a grid over the devices' extent is tried, the one whose
crossing links' mean training residual removes the most squared error wins, then each edge is refined.
Boxes around a transmitter are not tried (those are per-transmitter offsets).
"""
from __future__ import annotations

import numpy as np

from .effect_base import Effect

GRID_CELLS = 12          # coarse grid over the longer side of the devices' extent
MAX_SHARE = 0.6          # a box crossed by more of the links than this is a gain offset, not an obstacle
MIN_CROSSING_ROWS = 10
CHUNK = 2000


def segments_cross_boxes(p0: np.ndarray, p1: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """[N, B] bool: whether the floor-plan segment p0 -> p1 ([N, 2] m) touches each box ([B, 4] x0, y0,
    x1, y1 m) (slab test; a segment ending inside a box counts)."""
    d = p1 - p0
    tmin = np.zeros((len(p0), len(boxes)))
    tmax = np.ones((len(p0), len(boxes)))
    ok = np.ones((len(p0), len(boxes)), bool)
    for a in (0, 1):
        lo, hi = boxes[None, :, a], boxes[None, :, a + 2]
        o, da = p0[:, a:a + 1], d[:, a:a + 1]
        flat = np.abs(da) < 1e-12
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (lo - o) / da, (hi - o) / da
        near, far = np.minimum(t1, t2), np.maximum(t1, t2)
        tmin = np.where(flat, tmin, np.maximum(tmin, near))
        tmax = np.where(flat, tmax, np.minimum(tmax, far))
        ok &= np.where(flat, (o >= lo) & (o <= hi), True)
    return ok & (tmin <= tmax)


def _box_grid(lo: np.ndarray, hi: np.ndarray, step: float) -> np.ndarray:
    """[B, 4] boxes with corners on a grid of `step` inside [lo, hi], sides up to MAX_SHARE of the extent."""
    xs = np.arange(lo[0], hi[0] + 1e-9, step)
    ys = np.arange(lo[1], hi[1] + 1e-9, step)
    out = []
    for wx in range(1, max(2, int(MAX_SHARE * len(xs)) + 1)):
        for wy in range(1, max(2, int(MAX_SHARE * len(ys)) + 1)):
            x0, y0 = np.meshgrid(xs[:len(xs) - wx], ys[:len(ys) - wy], indexing="ij")
            x0, y0 = x0.reshape(-1), y0.reshape(-1)
            out.append(np.stack([x0, y0, x0 + wx * step, y0 + wy * step], 1))
    return np.concatenate(out) if out else np.zeros((0, 4))


class Obstacle(Effect):
    """An unmodelled obstacle: a loss (or gain) on the links crossing a box of the floor plan; the
    residual clusters on the map (receiver cells behind it, seen from each transmitter)."""

    name, title = "obstacle", "unmodelled obstacle (box on the floor plan)"
    params = ("loss_db", "x0_m", "y0_m", "x1_m", "y1_m")

    def applies(self, rows):
        if rows.monostatic:
            return False, "monostatic: no links across a floor plan"
        xy = np.concatenate([rows.tx_m[:, :2], rows.rx_m[:, :2]])
        if np.ptp(xy, axis=0).min() < 1.0:
            return False, "the devices span less than 1 m on the floor plan"
        if rows.train.sum() < 5 * MIN_CROSSING_ROWS:
            return False, f"fewer than {5 * MIN_CROSSING_ROWS} training rows"
        return True, ""

    def correction(self, x, rows, base_db):
        return x[0] * segments_cross_boxes(rows.tx_m[:, :2], rows.rx_m[:, :2], np.asarray(x[1:5])[None])[:, 0]

    def _score(self, s, n, p0, p1, boxes, tx_xy):
        """(SSE reduction [B], mean residual of the crossing rows [B]) of each box, from the residual sum s
        and the row count n of each distinct link [K] (floor-plan segments p0 -> p1 [K, 2])."""
        gains, means = np.full(len(boxes), -np.inf), np.zeros(len(boxes))
        for c in range(0, len(boxes), CHUNK):
            b = boxes[c:c + CHUNK]
            m = segments_cross_boxes(p0, p1, b)
            cnt = n @ m
            tot = s @ m
            mean = tot / np.maximum(cnt, 1)
            has_tx = np.any((tx_xy[:, None, 0] >= b[None, :, 0]) & (tx_xy[:, None, 0] <= b[None, :, 2])
                            & (tx_xy[:, None, 1] >= b[None, :, 1]) & (tx_xy[:, None, 1] <= b[None, :, 3]), axis=0)
            valid = (cnt >= MIN_CROSSING_ROWS) & (cnt <= MAX_SHARE * n.sum()) & ~has_tx
            gains[c:c + CHUNK] = np.where(valid, tot * mean, -np.inf)
            means[c:c + CHUNK] = mean
        return gains, means

    def fit(self, rows, base_db, mask):
        r = (rows.meas_db - base_db)[mask]
        r = r - np.median(r)     # a shared offset is not the obstacle's
        seg = np.concatenate([rows.tx_m[mask, :2], rows.rx_m[mask, :2]], 1)
        links, inv = np.unique(np.round(seg, 4), axis=0, return_inverse=True)   # rows of a link cross alike
        inv = inv.reshape(-1)
        s, n = np.bincount(inv, weights=r), np.bincount(inv).astype(float)
        p0, p1 = links[:, :2], links[:, 2:]
        tx_xy = np.unique(np.round(rows.tx_m[:, :2], 3), axis=0)
        xy = np.concatenate([rows.tx_m[:, :2], rows.rx_m[:, :2]])
        lo, hi = xy.min(0), xy.max(0)
        step = float(np.max(hi - lo)) / GRID_CELLS
        boxes = _box_grid(lo, hi, step)
        gains, _ = self._score(s, n, p0, p1, boxes, tx_xy)
        if not np.isfinite(gains.max()):
            return np.array([0.0, lo[0], lo[1], lo[0], lo[1]])
        box = boxes[int(np.argmax(gains))].copy()
        best = float(gains.max())
        for _ in range(2):                       # refine each edge on a quarter step
            for e in range(4):
                trial = np.repeat(box[None], 9, 0)
                trial[:, e] = box[e] + step / 4 * np.arange(-4, 5)
                trial = trial[(trial[:, 2] > trial[:, 0]) & (trial[:, 3] > trial[:, 1])]
                g, _ = self._score(s, n, p0, p1, trial, tx_xy)
                if g.max() > best:
                    best, box = float(g.max()), trial[int(np.argmax(g))].copy()
        crossing = segments_cross_boxes(rows.tx_m[mask, :2], rows.rx_m[mask, :2], box[None])[:, 0]
        loss = float(np.median((rows.meas_db - base_db)[mask][crossing]) - np.median((rows.meas_db - base_db)[mask][~crossing]))
        return np.concatenate([[loss], box])
