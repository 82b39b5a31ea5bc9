"""Validation folds for choosing between models on the training rows alone (the material sharing and
the edge waves in rf-fit; the residual's folds for a held-out range), shaped like the test of the
protocol (rfir_stages.model.split_protocols). The test rows are never looked at."""
from __future__ import annotations

import numpy as np


def validation_rows(protocol: str, aspect_deg: np.ndarray | None, range_m: np.ndarray | None) -> tuple[np.ndarray, str]:
    """Training rows [V] to hold out when choosing between models, shaped like the protocol's test.

    aspect_deg / range_m: of the training rows (None when the file has none). "sector:A:B": the
    tenth of the training rows nearest the held-out sector (on both sides of it: an extrapolation
    like the test's); "range:R": the rows at the training range nearest R; otherwise every 10th
    row (an interpolation, like the data / every-N protocols). Returns (indices, description)."""
    name, _, arg = protocol.partition(":")
    m = len(aspect_deg) if aspect_deg is not None else len(range_m) if range_m is not None else 0
    if name == "sector" and aspect_deg is not None and m >= 10:
        gap = gap_to_sector_deg(aspect_deg, arg)
        return np.sort(np.argsort(gap, kind="stable")[:m // 10]), "the tenth of the training rows next to the sector"
    if name == "range" and range_m is not None:
        rng = np.asarray(range_m, np.float64)
        ranges = np.unique(np.round(rng, 6))
        if ranges.size >= 2:
            near = ranges[np.argmin(np.abs(ranges - float(arg)))]
            return np.flatnonzero(np.abs(rng - near) < 1e-6), f"the training rows at {near:g} m"
    return np.arange(5, m, 10) if m > 5 else np.arange(0, m, 10), "every 10th training row"


MIN_VALIDATION_LINKS = 50   # fewer held-out links than this decide a model by noise
KFOLD_MAX_LINKS = 60        # k-fold (several fits per candidate) only up to this many training links (cost)
KFOLDS = 3


def validation_folds(protocol: str, aspect_deg: np.ndarray | None, range_m: np.ndarray | None,
                     min_links: int = MIN_VALIDATION_LINKS) -> tuple[list[np.ndarray], str]:
    """Folds of training rows to hold out when choosing between models: each candidate is fitted on
    the rest of each fold and scored on the fold; the scores pool every fold's links.

    One fold (validation_rows) when it holds >= min_links links. Otherwise, shaped like the
    protocol's test: "range:R": each training range in turn (leave-one-range-out); "sector:A:B":
    a larger share next to the sector (up to a third of the training rows); "data" / "every-N":
    KFOLDS folds of whole aspects dealt at random (aspect_folds) covering every training row when there
    are at most KFOLD_MAX_LINKS of them (the fits are cheap there), else every third row. Returns (folds,
    description); the caller warns when the folds still hold fewer than min_links links."""
    val, how = validation_rows(protocol, aspect_deg, range_m)
    m = len(aspect_deg) if aspect_deg is not None else len(range_m) if range_m is not None else 0
    if len(val) >= min_links or m < 10:
        return [val], how
    name, _, arg = protocol.partition(":")
    if name == "range" and range_m is not None:
        rng = np.round(np.asarray(range_m, np.float64), 6)
        ranges = np.unique(rng)
        if ranges.size >= 2:
            return [np.flatnonzero(rng == r) for r in ranges], f"each training range in turn ({ranges.size} folds)"
        return [val], how
    if name == "sector" and aspect_deg is not None:
        gap = gap_to_sector_deg(aspect_deg, arg)
        n = min(min_links, m // 3)
        return [np.sort(np.argsort(gap, kind="stable")[:n])], f"the {n} training rows next to the sector"
    if m <= KFOLD_MAX_LINKS:
        return aspect_folds(aspect_deg, m, KFOLDS), f"{KFOLDS}-fold, whole training aspects dealt at random"
    return [np.arange(1, m, 3)], "every 3rd training row"


FOLD_SEED = 0   # the deal of aspects to folds is fixed: the same rows choose the same model


def aspect_folds(aspect_deg: np.ndarray | None, m: int, k: int) -> list[np.ndarray]:
    """k folds of the m training rows, each aspect's rows (every range of it) in one fold, the aspects
    dealt to the folds in a fixed random order (rows one by one where there are no aspects).

    Not interleaved: few aspects at a regular spacing, every k-th held out, line up with the object's
    symmetry (12 aspects 30 degrees apart, every 3rd in turn: four aspects 90 degrees apart, a box's
    four broadsides in one fold, none in the others), and a fold that holds one range of an aspect
    while another range of it trains is easier than the test, which holds out whole aspects."""
    key = np.arange(m) if aspect_deg is None else aspect_index(aspect_deg)
    num = int(key.max()) + 1 if m else 0
    fold_of = np.empty(num, np.int64)
    fold_of[np.random.default_rng(FOLD_SEED).permutation(num)] = np.arange(num) % k
    return [np.flatnonzero(fold_of[key] == j) for j in range(k)]


def distinct_aspects(aspect_deg: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the distinct aspects [A] degrees in [0, 360), sorted; each row's index among them [M] int): aspects
    equal to 1e-6 degree modulo 360 are one, so rows of one aspect at several ranges share an index."""
    key = np.round(np.mod(np.asarray(aspect_deg, np.float64), 360.0), 6)
    uniq, inv = np.unique(key, return_inverse=True)
    return uniq, inv.ravel()


def aspect_index(aspect_deg: np.ndarray) -> np.ndarray:
    """[M] int: each row's aspect among the distinct aspects (distinct_aspects)."""
    return distinct_aspects(aspect_deg)[1]


def gap_to_sector_deg(aspect_deg: np.ndarray, sector: str) -> np.ndarray:
    """[M] degrees from each aspect to the nearer edge of the sector "A:B" ([A, B) degrees, wrapping)."""
    a, b = (float(x) % 360.0 for x in sector.split(":"))
    deg = np.mod(np.asarray(aspect_deg, np.float64), 360.0)
    return np.minimum(np.mod(deg - b, 360.0), np.mod(a - deg, 360.0))
