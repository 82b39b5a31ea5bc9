"""Per-device offsets (calibration): each transmitter, or each receiver, reads its own constant dB off.

A device is a distinct antenna position (rounded to DEVICE_TOL_M). The parameter vector x holds the K
offsets [dB] followed by the K positions [m] (x, y, z each), so a recorded chain applies the offsets to
new links of the same devices (a link of an unknown device gets none). Only the K offsets are fitted:
the complexity the ranking penalises is K.
"""
from __future__ import annotations

import numpy as np

from .effect_base import Effect
from .rows import Rows

DEVICE_TOL_M = 0.01
MIN_ROWS_PER_DEVICE = 3


def _positions(rows: Rows, side: str) -> np.ndarray:
    return rows.tx_m if side == "tx" else rows.rx_m


def _device_index(pos_m: np.ndarray, devices_m: np.ndarray) -> np.ndarray:
    """[N] index of the device at each position (-1: none within DEVICE_TOL_M)."""
    uniq, inv = np.unique(pos_m, axis=0, return_inverse=True)   # many rows share a position: match each once
    d = np.linalg.norm(uniq[:, None, :] - devices_m[None, :, :], axis=2)
    idx = np.argmin(d, axis=1)
    return np.where(d[np.arange(len(uniq)), idx] <= DEVICE_TOL_M, idx, -1)[inv.reshape(-1)]


class _DeviceOffsets(Effect):
    side = "tx"
    word = "Tx"

    def _devices(self, rows: Rows) -> np.ndarray:
        return np.unique(np.round(_positions(rows, self.side) / DEVICE_TOL_M) * DEVICE_TOL_M, axis=0)

    def applies(self, rows):
        if rows.monostatic:
            return False, "monostatic: the transmitter is the receiver"
        dev = self._devices(rows)
        if not 2 <= len(dev) <= max(64, rows.num // 6):
            return False, f"{len(dev)} distinct {self.word} positions (needs 2 to {max(64, rows.num // 6)})"
        per = np.bincount(_device_index(_positions(rows, self.side), dev)[rows.train], minlength=len(dev))
        if np.median(per) < MIN_ROWS_PER_DEVICE:
            return False, f"fewer than {MIN_ROWS_PER_DEVICE} training rows per {self.word}"
        return True, ""

    def correction(self, x, rows, base_db):
        k = len(x) // 4
        offsets, devices = np.asarray(x[:k]), np.asarray(x[k:]).reshape(k, 3)
        idx = _device_index(_positions(rows, self.side), devices)
        return np.where(idx >= 0, offsets[np.maximum(idx, 0)], 0.0)

    def fit(self, rows, base_db, mask):
        """Robust offset per device: the median training residual of its rows (0 where it has none)."""
        devices = self._devices(rows)
        idx = _device_index(_positions(rows, self.side), devices)
        r = rows.meas_db - base_db
        offsets = np.array([np.median(r[mask & (idx == i)]) if np.any(mask & (idx == i)) else 0.0
                            for i in range(len(devices))])
        return np.concatenate([offsets, devices.reshape(-1)])

    def describe(self, x):
        k = len(x) // 4
        devices = np.asarray(x[k:]).reshape(k, 3)
        out = {f"{self.word} ({p[0]:.2f}, {p[1]:.2f}, {p[2]:.2f}) m": float(v) for v, p in zip(x[:k], devices)}
        out["spread_db"] = float(np.ptp(x[:k]))
        return out

    def num_free(self, x):
        return len(x) // 4


class TransmitterOffsets(_DeviceOffsets):
    """A different gain per transmitter (power or cable calibration): the residual is a constant per
    transmitter, different between them (one shared constant is gain_offset, with one parameter)."""

    name, title, params = "tx_offsets", "per-transmitter offsets (device calibration)", ("offset_db per Tx",)
    side, word = "tx", "Tx"


class ReceiverOffsets(_DeviceOffsets):
    """A different gain per receiver (receiver calibration): the residual is a constant per receiver
    position, the same whichever transmitter it hears."""

    name, title, params = "rx_offsets", "per-receiver offsets (device calibration)", ("offset_db per Rx",)
    side, word = "rx", "Rx"
