"""Flashes: the specular peaks of a measured RCS curve, and how well each method predicts those on test rows.

Definition (one place; `predict rcs` writes it as `flashes_test` in its results JSON):
- a curve is the measured RCS (dBsm) over aspect at one range and one frequency: the rows of that
  range, every split (train, test, unused), sorted by aspect;
- a flash is a local maximum of that curve whose topographic prominence (scipy.signal.find_peaks) is
  at least `min_prominence_db` dB and whose row is a test row. A curve whose aspects cover the
  circle evenly (largest gap at most 1.5 times the median step) is treated as circular (the flash
  at 0 deg sees 359 deg beside it); otherwise the ends are not peaks;
- a method's predicted peak is the maximum of its prediction over the test rows of the same curve
  within +-`window_deg` of the flash (a glint shifted by a degree or two still counts; training rows
  are not in the window, where a method's value is a fit, not a prediction);
- error = predicted peak - measured peak (dB); a flash is predicted when |error| <= `tolerance_db`.

The thresholds are the [predict.flashes] table of configs/predict.toml.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import find_peaks


def flash_defaults() -> dict:
    """The [predict.flashes] table of configs/predict.toml (what a caller's config does not set)."""
    from rfir_core.config import load_defaults

    return dict(load_defaults().get("predict", {}).get("flashes", {}))


def _is_circular(aspect_deg: np.ndarray) -> bool:
    """True when the sorted aspects [N] deg cover the circle evenly (no gap above 1.5 median steps)."""
    if aspect_deg.size < 3:
        return False
    gaps = np.diff(np.concatenate([aspect_deg, aspect_deg[:1] + 360.0]))
    return bool(gaps.max() <= 1.5 * np.median(gaps))


def find_flashes(aspect_deg: np.ndarray, values_db: np.ndarray, min_prominence_db: float):
    """Peaks of one curve: aspect_deg [N] deg (sorted, in [0, 360)), values_db [N] dB (finite).

    Returns (indices [P] into the curve, prominences [P] dB). A circular curve is tiled three times so
    that peaks and their prominence see across 359/0 deg; only peaks of the middle copy are kept
    (a plateau across the seam is reported once)."""
    n = values_db.size
    if n < 3:
        return np.zeros(0, int), np.zeros(0)
    if _is_circular(aspect_deg):
        idx, props = find_peaks(np.tile(values_db, 3), prominence=min_prominence_db)
        keep = (idx >= n) & (idx < 2 * n)
        return idx[keep] - n, props["prominences"][keep]
    idx, props = find_peaks(values_db, prominence=min_prominence_db)
    return idx, props["prominences"]


def _circular_distance_deg(a: np.ndarray, b: float) -> np.ndarray:
    return np.abs(np.mod(a - b + 180.0, 360.0) - 180.0)


def score_flashes(aspect_rad: np.ndarray, range_m: np.ndarray, freqs_hz: np.ndarray, measured_db: np.ndarray,
                  test: np.ndarray, predictions: dict, *, min_prominence_db: float, window_deg: float,
                  tolerance_db: float) -> dict:
    """The flashes on test rows and each method's predicted peak (see the module docstring).

    aspect_rad [L] rad, range_m [L] m, freqs_hz [F] Hz, measured_db [L, F] dBsm, test [L] bool (the
    test rows); predictions: method name -> [L, F] dBsm (NaN where the method predicts nothing; only
    its test rows are read). Returns a JSON-ready dict: the thresholds, `num_flashes`, per method
    `num_within_tolerance`, `num_predicted` (flashes with a finite prediction in the window) and
    `median_abs_error_db` (None without any), per curve its flash count, and per flash its aspect,
    range, frequency, measured peak and prominence, each method's predicted peak and error. No NaN:
    a missing value is None."""
    aspect_deg = np.mod(np.degrees(np.asarray(aspect_rad, np.float64)), 360.0)
    range_m = np.asarray(range_m, np.float64)
    measured_db = np.asarray(measured_db, np.float64)
    test = np.asarray(test, bool)
    flashes, curves = [], []
    for r in np.unique(np.round(range_m, 6)):
        rows = np.flatnonzero(np.abs(range_m - r) < 1e-6)
        for k, f in enumerate(np.asarray(freqs_hz, np.float64)):
            ok = rows[np.isfinite(measured_db[rows, k])]
            ok = ok[np.argsort(aspect_deg[ok], kind="stable")]
            peaks, prominence = find_flashes(aspect_deg[ok], measured_db[ok, k], min_prominence_db)
            count = 0
            for p, prom in zip(peaks, prominence):
                row = ok[p]
                if not test[row]:
                    continue
                count += 1
                near = ok[test[ok] & (_circular_distance_deg(aspect_deg[ok], aspect_deg[row]) <= window_deg + 1e-9)]
                entry = {"aspect_deg": float(aspect_deg[row]), "range_m": float(r), "freq_hz": float(f),
                         "measured_dbsm": float(measured_db[row, k]), "prominence_db": float(prom),
                         "predicted_dbsm": {}, "error_db": {}}
                for name, pred in predictions.items():
                    v = np.asarray(pred, np.float64)[near, k]
                    v = v[np.isfinite(v)]
                    peak = float(v.max()) if v.size else None
                    entry["predicted_dbsm"][name] = peak
                    entry["error_db"][name] = None if peak is None else peak - entry["measured_dbsm"]
                flashes.append(entry)
            curves.append({"range_m": float(r), "freq_hz": float(f), "num_flashes": count})
    methods = {}
    for name in predictions:
        err = np.array([abs(e["error_db"][name]) for e in flashes if e["error_db"][name] is not None])
        methods[name] = {"num_predicted": int(err.size),
                         "num_within_tolerance": int(np.sum(err <= tolerance_db)),
                         "median_abs_error_db": float(np.median(err)) if err.size else None}
    return {"min_prominence_db": float(min_prominence_db), "window_deg": float(window_deg),
            "tolerance_db": float(tolerance_db), "num_flashes": len(flashes), "methods": methods,
            "curves": curves, "flashes": flashes}
