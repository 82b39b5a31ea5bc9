"""Materials for Gaussians no training link sees.

A Gaussian hidden from every training link (the underside of a brick, the inside of a stack) gets
no gradient, so it keeps the initial material (|Gamma| = 0.5, R = 4: bright and broad). Nothing
measured says what it is, but an edit can expose it (a rotated part, a removed object), and then
its initial value is a guess that the data contradict: on the lego, 2937 of 7712 surfels were never
seen, and rotating the top bricks made predict add 6 dB of lobes that the simulator did not show.
The best guess is the material of the nearest seen Gaussians of the same object: each unseen
Gaussian takes the median (circular mean for the phase) of its k nearest seen Gaussians with the
same label (any label when the object has none seen, or the scene has no labels).
"""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .fit import FitResult

# An exposure (summed |dL/dtheta| over the fit) below this fraction of the median seen exposure
# counts as unseen: Adam moves such parameters by less than its epsilon-limited step.
UNSEEN_REL = 1e-9


def unseen_mask(exposure: np.ndarray) -> np.ndarray:
    """[G] bool: True where a Gaussian received (almost) no gradient."""
    e = np.asarray(exposure, np.float64)
    positive = e[e > 0]
    if positive.size == 0:
        return np.zeros(len(e), bool)
    return e <= UNSEEN_REL * float(np.median(positive))


def fill_unseen(result: FitResult, unseen: np.ndarray, means_m: np.ndarray, labels: np.ndarray | None,
                k: int = 8) -> int:
    """Replace the materials of the unseen Gaussians of `result` in place (module docstring).

    unseen [G] bool; means_m [G, 3] m; labels [G] int or None. Returns how many were filled."""
    unseen = np.asarray(unseen, bool)
    seen = np.flatnonzero(~unseen)
    if not unseen.any() or seen.size == 0:
        return 0
    arrays = [a for a in (result.opacity, result.roughness, result.gamma_abs, result.diffuse,
                          result.diffuse_roughness) if a is not None]
    phase = result.gamma_phase_rad
    groups = [(np.flatnonzero(unseen), seen)]
    if labels is not None:
        labels = np.asarray(labels)
        groups, rest = [], []
        for lab in np.unique(labels[unseen]):
            target = np.flatnonzero(unseen & (labels == lab))
            donors = seen[labels[seen] == lab]
            if donors.size:
                groups.append((target, donors))
            else:
                rest.append(target)
        if rest:
            groups.append((np.concatenate(rest), seen))
    for target, donors in groups:
        kk = min(k, donors.size)
        _, nn = cKDTree(means_m[donors]).query(means_m[target], k=kk)
        nn = donors[np.asarray(nn).reshape(len(target), kk)]
        for a in arrays:
            a[target] = np.median(a[nn], axis=1)
        phase[target] = np.angle(np.exp(1j * phase[nn]).mean(axis=1))
    return int(unseen.sum())
