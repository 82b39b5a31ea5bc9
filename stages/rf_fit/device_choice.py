"""Which device gains a room fit of measured data gets ("auto"): chosen by validation on held-out positions.

A gain per device position fits the training links exactly and carries nowhere (a walk survey's receiver
carried to many positions would get one gain per position, a training error of zero and a test error worse
than no gains). So the choice between no gains, a gain per transmitter, per receiver or both is made
on links at positions the fit did not see: the materials are fitted once without gains on the other links,
each candidate's gains are then the ridge solution of that fit's residuals (device_gains.ridge_gains, the
fit's own prior), and a candidate wins only where it lowers the held-out error by MARGIN_DB over every
simpler one. A device the held-out links share with the fit links (an anchor, the one roaming receiver told
apart by its id) carries its gain to them; a device at a held-out position gets none, as at prediction.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from rfir_stages.model.device_gains import SIDES, device_index, ridge_gains

HELD_SHARE = 0.2            # share of the roaming side's positions held out
MIN_VALIDATION_LINKS = 20   # fewer held-out links than this: no gains (the choice would be noise)
MARGIN_DB = 0.02            # a candidate must lower the held-out MAE by this over each simpler one
ORDER = ("off", "tx", "rx", "both")


@dataclass
class DeviceChoice:
    """The chosen device gains ("off", "tx", "rx", "both"), why, and the held-out MAE [dB] of each candidate."""

    which: str
    reason: str
    scores: dict = field(default_factory=dict)


def held_out_rows(tx_m: np.ndarray, rx_m: np.ndarray, seed: int) -> tuple[np.ndarray, str]:
    """([M] bool, side name): the links whose end on the side with more distinct positions (the roaming side)
    lies at one of HELD_SHARE of those positions, drawn with `seed`."""
    sides = {"tx": np.asarray(tx_m), "rx": np.asarray(rx_m)}
    counts = {s: len(device_index(p)[0]) for s, p in sides.items()}
    side = "rx" if counts["rx"] >= counts["tx"] else "tx"
    _, where, _ = device_index(sides[side])
    num = counts[side]
    held = np.random.default_rng(seed).permutation(num)[: max(1, int(round(HELD_SHARE * num)))]
    return np.isin(where, held), side


def choose_device_gains(tx_m: np.ndarray, rx_m: np.ndarray, ids: dict, target_db: np.ndarray, prior_db: float,
                        fit_without_gains: Callable[[np.ndarray], np.ndarray], seed: int) -> DeviceChoice:
    """Choose the device gains of links tx_m / rx_m [M, 3] m with measured path gains target_db [M] dB.

    ids: {"tx": [M] int or None, "rx": ...}, the file's device ids. fit_without_gains(rows [K] int64) fits the
    materials on those links without device gains and returns the predicted path gain [M] dB of every link."""
    index = {s: device_index(p, ids.get(s))[1] for s, p in zip(SIDES, (tx_m, rx_m))}
    sides = [s for s in SIDES if index[s].max(initial=-1) + 1 >= 2]
    if not sides:
        return DeviceChoice("off", "one device on each side: its gain is the system gain")
    held, side = held_out_rows(tx_m, rx_m, seed)
    if held.sum() < MIN_VALIDATION_LINKS or (~held).sum() < MIN_VALIDATION_LINKS:
        return DeviceChoice("off", f"too few links ({len(held)}) to validate device gains on held-out positions; "
                                   "rf_fit.room.device_gains sets them")
    train = np.flatnonzero(~held)
    pred = fit_without_gains(train)
    residual = np.asarray(target_db, np.float64) - pred
    scores = {"off": float(np.abs(residual[held]).mean())}
    for which in ORDER[1:]:
        use = [s for s in SIDES if which in (s, "both") and s in sides]
        if len(use) != (2 if which == "both" else 1):
            continue
        gains = ridge_gains(residual[train], {s: index[s][train] for s in use}, prior_db)
        add = sum(np.pad(gains[s], (0, index[s].max() + 1 - len(gains[s])))[index[s][held]] for s in use)
        scores[which] = float(np.abs(residual[held] - add).mean())
    best = "off"
    for which in ORDER[1:]:
        if which in scores and scores[which] < scores[best] - MARGIN_DB:
            best = which
    shown = ", ".join(f"{k} {v:.2f}" for k, v in scores.items())
    reason = (f"auto: validated on {int(held.sum())} training links at {HELD_SHARE:.0%} of the {side} positions "
              f"held out of the fit (MAE dB: {shown}); rf_fit.room.device_gains sets them")
    return DeviceChoice(best, reason, scores)
