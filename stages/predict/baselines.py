"""Simple baselines for RCS versus aspect, on the same split as the model.

For every test row, among the training rows with the same range (and per frequency column):
- nearest: copy the value of the training aspect nearest on the circle;
- linear: interpolate linearly (in dB) between the training aspects on either side (circular).
"""
from __future__ import annotations

import numpy as np


def _circular_neighbours(train_asp: np.ndarray, query: np.ndarray):
    """Indices (into train_asp) of the neighbours below and above each query, and the weight of 'above'."""
    order = np.argsort(train_asp)
    a = train_asp[order]
    two_pi = 2 * np.pi
    ext = np.concatenate([a[-1:] - two_pi, a, a[:1] + two_pi])
    ext_idx = np.concatenate([order[-1:], order, order[:1]])
    q = np.mod(query, two_pi)
    hi = np.searchsorted(ext, q, side="left").clip(1, len(ext) - 1)
    lo = hi - 1
    span = ext[hi] - ext[lo]
    w = np.where(span > 0, (q - ext[lo]) / np.where(span > 0, span, 1.0), 0.0)
    return ext_idx[lo], ext_idx[hi], w


def aspect_baselines(aspect_rad: np.ndarray, range_m: np.ndarray, values_db: np.ndarray, train: np.ndarray,
                     test: np.ndarray) -> dict[str, np.ndarray]:
    """{'nearest': [T, F], 'linear': [T, F]} predictions for the `test` rows from the `train` rows.

    aspect_rad [L], range_m [L], values_db [L, F]; train / test: row indices. Rows whose range has
    no training rows get NaN.
    """
    values_db = np.asarray(values_db, dtype=np.float64)
    out = {k: np.full((len(test), values_db.shape[1]), np.nan) for k in ("nearest", "linear")}
    for r in np.unique(np.round(range_m[test], 6)):
        tr = train[np.abs(range_m[train] - r) < 1e-6]
        sel = np.flatnonzero(np.abs(range_m[test] - r) < 1e-6)
        if tr.size == 0:
            continue
        lo, hi, w = _circular_neighbours(aspect_rad[tr], aspect_rad[test[sel]])
        v = values_db[tr]
        out["linear"][sel] = (1 - w)[:, None] * v[lo] + w[:, None] * v[hi]
        out["nearest"][sel] = np.where((w <= 0.5)[:, None], v[lo], v[hi])
    return out


def range_baselines(aspect_rad: np.ndarray, range_m: np.ndarray, values_db: np.ndarray, train: np.ndarray,
                    test: np.ndarray) -> dict[str, np.ndarray]:
    """{'nearest_range': [T, F], 'linear_range': [T, F]}: for each test row, the training rows at the
    same aspect; copy the nearest range, or interpolate linearly in range (clamped at the ends).
    RCS should not depend on range in the far field, so these are the natural range baselines."""
    values_db = np.asarray(values_db, dtype=np.float64)
    out = {k: np.full((len(test), values_db.shape[1]), np.nan) for k in ("nearest_range", "linear_range")}
    for i, row in enumerate(test):
        same = train[np.abs(np.angle(np.exp(1j * (aspect_rad[train] - aspect_rad[row])))) < 1e-6]
        if same.size == 0:
            continue
        r = range_m[same]
        order = np.argsort(r)
        r, v = r[order], values_db[same][order]
        out["nearest_range"][i] = v[np.argmin(np.abs(r - range_m[row]))]
        for k in range(values_db.shape[1]):
            out["linear_range"][i, k] = np.interp(range_m[row], r, v[:, k])
    return out


def baselines_beating_model(metrics: dict, rows: str = "test") -> list[str]:
    """One warning per fitted baseline that predicts the scored rows better than the model.

    metrics: the model's MAE as 'mae_db' and each baseline's as 'baseline_<name>_mae_db' (dB, the
    same rows). A model that a simple baseline beats is no better than the baseline there."""
    model = metrics.get("mae_db")
    if model is None or not np.isfinite(model):
        return []
    out = []
    for key, value in metrics.items():
        if key.startswith("baseline_") and key.endswith("_mae_db") and np.isfinite(value) and value < model:
            name = key[len("baseline_"):-len("_mae_db")].replace("_", " ")
            out.append(f"the {name} baseline beats rfir on the {rows} rows: {value:.2f} dB against {model:.2f} dB MAE")
    return out
