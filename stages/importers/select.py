"""Row selection over a measurements artifact (`--freq`, `--range`, `--aspects`) and row counts.

A selection names frequencies [Hz], ranges [m] and aspects [deg]; each part left empty keeps
everything. Aspects: "A:B" is the half-open interval [A, B) (wrapping: "315:45"), "A" one aspect,
"A:B:STEP" the aspects A, A + STEP, ... below B; several parts joined by commas. Matching
tolerances: frequencies 1e-6 relative, ranges RANGE_TOL_M, single aspects ASPECT_TOL_DEG.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rfir_core.errors import ConfigError, StageError

RANGE_TOL_M = 1e-3
ASPECT_TOL_DEG = 1e-6


@dataclass(frozen=True)
class RowSelection:
    """freqs_hz, ranges_m: values to keep; aspects_deg: ((lo, hi), ...) intervals [lo, hi) in degrees,
    a single aspect as (a, a). Empty tuples keep everything."""

    freqs_hz: tuple = ()
    ranges_m: tuple = ()
    aspects_deg: tuple = ()

    def __bool__(self) -> bool:
        return bool(self.freqs_hz or self.ranges_m or self.aspects_deg)

    def describe(self) -> str:
        parts = []
        if self.freqs_hz:
            parts.append("--freq " + ",".join(f"{f:g}" for f in self.freqs_hz))
        if self.ranges_m:
            parts.append("--range " + ",".join(f"{r:g}" for r in self.ranges_m))
        if self.aspects_deg:
            parts.append("--aspects " + ",".join(f"{a:g}" if a == b else f"{a:g}:{b:g}" for a, b in self.aspects_deg))
        return " ".join(parts) or "all rows"


def _floats(text: str, what: str) -> list[float]:
    try:
        values = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ConfigError(f"{what} {text!r}: expected numbers separated by commas") from None
    if not values or not np.all(np.isfinite(values)):
        raise ConfigError(f"{what} {text!r}: expected finite numbers separated by commas")
    return values


def parse_aspects(text: str) -> tuple:
    """'0:90', '315:45', '45', '0:360:2' (comma-joined) -> ((lo, hi), ...) in degrees."""
    out = []
    for part in text.split(","):
        pieces = part.strip().split(":")
        try:
            nums = [float(p) for p in pieces]
        except ValueError:
            nums = []
        if not nums or not np.all(np.isfinite(nums)) or len(nums) > 3 or (len(nums) == 3 and nums[2] <= 0):
            raise ConfigError(f"--aspects {text!r}: expected A:B (degrees, [A, B)), A, or A:B:STEP, comma-joined")
        if len(nums) == 1:
            out.append((nums[0], nums[0]))
        elif len(nums) == 2:
            out.append((nums[0], nums[1]))
        else:
            out += [(a, a) for a in np.arange(nums[0], nums[1] - 1e-9, nums[2])]
    return tuple((float(a), float(b)) for a, b in out)


def parse_selection(freq: str | list | None = None, range_m: str | None = None, aspects: str | None = None) -> RowSelection:
    """A RowSelection from command-line texts (freq may also be a list of numbers)."""
    if isinstance(freq, (list, tuple)):
        freqs = [float(f) for f in freq]
    else:
        freqs = _floats(freq, "--freq") if freq else []
    return RowSelection(tuple(freqs), tuple(_floats(range_m, "--range") if range_m else ()),
                        parse_aspects(aspects) if aspects else ())


def aspect_mask(aspect_deg: np.ndarray, intervals: tuple) -> np.ndarray:
    """[L] bool: aspects inside any interval [lo, hi) (wrapping mod 360) or equal to a single one."""
    deg = np.mod(np.asarray(aspect_deg, np.float64), 360.0)
    keep = np.zeros(deg.shape, bool)
    for lo, hi in intervals:
        if lo == hi:
            keep |= np.abs((deg - lo + 180.0) % 360.0 - 180.0) <= ASPECT_TOL_DEG
        elif hi - lo >= 360.0:
            keep[:] = True
        else:
            a, b = lo % 360.0, hi % 360.0
            keep |= ((deg >= a) & (deg < b)) if a < b else ((deg >= a) | (deg < b))
    return keep


def select_rows(meas, sel: RowSelection, where: str, rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(rows [R] int, cols [K] int) of `meas` kept by `sel`, among `rows` (default: all rows).

    Raises StageError (one line, naming what the file holds) when a part keeps nothing."""
    n_rows = len(np.asarray(meas["tx_pos"]))
    rows = np.arange(n_rows) if rows is None else np.asarray(rows, np.int64)
    f_all = np.asarray(meas["freq_hz"], np.float64)
    cols = np.arange(len(f_all))
    if sel.freqs_hz:
        want = np.asarray(sel.freqs_hz, np.float64)
        cols = np.flatnonzero(np.any(np.abs(f_all[:, None] - want[None]) <= 1e-6 * want[None], axis=1))
        if cols.size == 0:
            raise StageError(f"{sel.describe()}: no such frequency in the file (it has "
                             f"{', '.join(f'{f:g}' for f in f_all[:8])} Hz)", path=where)
    keep = np.ones(len(rows), bool)
    if sel.ranges_m:
        rng = meas.get("range_m")
        if rng is None:
            raise StageError("--range needs range_m in the measurements", path=where)
        rng = np.asarray(rng, np.float64)
        keep &= np.any(np.abs(rng[rows, None] - np.asarray(sel.ranges_m)[None]) <= RANGE_TOL_M, axis=1)
    if sel.aspects_deg:
        asp = meas.get("aspect_rad")
        if asp is None:
            raise StageError("--aspects needs aspect_rad in the measurements", path=where)
        keep &= aspect_mask(np.degrees(np.asarray(asp, np.float64))[rows], sel.aspects_deg)
    if not keep.any():
        held = []
        if meas.get("range_m") is not None:
            held.append("ranges " + ", ".join(f"{r:g}" for r in np.unique(np.round(meas["range_m"], 6))[:8]) + " m")
        if meas.get("aspect_rad") is not None:
            deg = np.degrees(np.asarray(meas["aspect_rad"], np.float64))
            held.append(f"aspects {deg.min():g}..{deg.max():g} deg")
        raise StageError(f"{sel.describe()} leaves no row of the {len(rows)} considered"
                         + (f" (the file has {'; '.join(held)})" if held else ""), path=where)
    return rows[keep], cols


def row_counts(meas) -> dict:
    """Counts for `rfir info`: {"frequency": {label: cells with a value}, "range": {label: rows},
    "split": {label: rows}} (range and split only when the file has them)."""
    pg = np.asarray(meas["path_gain_db"], np.float64)
    out = {"frequency": {f"{f / 1e9:g} GHz": int(np.isfinite(pg[:, k]).sum())
                         for k, f in enumerate(np.asarray(meas["freq_hz"], np.float64))}}
    if meas.get("range_m") is not None:
        values, counts = np.unique(np.round(np.asarray(meas["range_m"], np.float64), 6), return_counts=True)
        out["range"] = {f"{v:g} m": int(c) for v, c in zip(values, counts)}
    if meas.get("split") is not None:
        names = {0: "train", 1: "test", -1: "unassigned"}
        values, counts = np.unique(np.asarray(meas["split"]), return_counts=True)
        out["split"] = {names.get(int(v), str(int(v))): int(c) for v, c in zip(values, counts)}
    return out
