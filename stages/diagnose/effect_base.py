"""The base of every candidate effect: P' = P + correction(x), parameters fitted on the training rows
(stages/diagnose/effects.py holds the catalogue)."""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares

from .rows import Rows

FLOOR = 1e-30


def _db(p):
    return 10 * np.log10(np.maximum(p, FLOOR))


def _add_power(base_db, add_lin):
    """dB correction of adding add_lin [linear] to the power 10^(base_db/10)."""
    return _db(10 ** (base_db / 10) + add_lin) - base_db


class Effect:
    """One candidate. Subclasses set name, title, params (names), x0 (starting points) and define
    correction(); applies() says whether the data can show the effect at all."""

    name = ""
    title = ""
    params: tuple = ()
    x0: tuple = ((),)
    lower: tuple | None = None
    upper: tuple | None = None
    needs_phase = False   # tested only where the measured complex channel is there

    def applies(self, rows: Rows) -> tuple[bool, str]:
        return True, ""

    def correction(self, x: np.ndarray, rows: Rows, base_db: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def fit(self, rows: Rows, base_db: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Parameters minimising a robust (soft L1, 1 dB scale) misfit of meas - base - correction on mask."""
        target = rows.meas_db - base_db
        best, best_cost = None, math.inf
        for x0 in self.x0:
            kw = {}
            if self.lower is not None:
                kw["bounds"] = (np.asarray(self.lower, float), np.asarray(self.upper, float))
            try:
                sol = least_squares(lambda x: (target - self.correction(x, rows, base_db))[mask], np.asarray(x0, float),
                                    loss="soft_l1", f_scale=1.0, max_nfev=200, **kw)
            except ValueError:
                continue
            if sol.cost < best_cost:
                best, best_cost = sol.x, sol.cost
        return np.asarray(best if best is not None else self.x0[0], float)

    def consistent(self, x: np.ndarray, rows: Rows, mask: np.ndarray) -> tuple[bool, str]:
        """Whether the fitted parameters agree with what else the data say (default: nothing else)."""
        return True, ""

    def describe(self, x: np.ndarray) -> dict:
        return {p: float(v) for p, v in zip(self.params, x)}

    def num_free(self, x: np.ndarray) -> int:
        """Parameters fitted to the data (the complexity the ranking penalises)."""
        return len(self.params)
