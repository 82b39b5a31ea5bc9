"""The rows diagnose works on: one per (link, frequency), with the features an engineer can act on."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

C0 = 299_792_458.0


@dataclass
class Rows:
    """Predicted and measured path gain per row, the split and the features (all arrays [N]).

    pred_db, meas_db: path gain [dB]; train/test: bool masks; tx_m, rx_m [N, 3] m; freq_hz;
    dist_m: Tx-Rx distance (monostatic: the range) [m]; monostatic: Tx and Rx co-located;
    aspect_rad, range_m: turntable aspect and range (RCS data) or None; crossings: objects the
    direct segment crosses (needs geometry) or None; meas_channel: the measured complex channel or
    None; curve_id: rows that share everything but the
    aspect (same range and frequency), for effects that shift the aspect; task: "rcs" or "rssi"."""

    pred_db: np.ndarray
    meas_db: np.ndarray
    train: np.ndarray
    test: np.ndarray
    tx_m: np.ndarray
    rx_m: np.ndarray
    freq_hz: np.ndarray
    task: str
    aspect_rad: np.ndarray | None = None
    range_m: np.ndarray | None = None
    crossings: np.ndarray | None = None
    meas_channel: np.ndarray | None = None   # [N] complex measured channel, where phase is measured
    pred_channel: np.ndarray | None = None   # [N] complex predicted channel, where the model gives phase
    incidence_deg: np.ndarray | None = None  # [N] on the dominant surface (monostatic rows with geometry)

    def __post_init__(self):
        self.dist_m = np.linalg.norm(self.rx_m - self.tx_m, axis=1)
        self.monostatic = bool(np.all(self.dist_m < 0.05))
        if self.monostatic and self.range_m is not None:
            self.dist_m = np.asarray(self.range_m, np.float64)
        self.wavelength_m = C0 / self.freq_hz
        if self.aspect_rad is not None:
            key = np.stack([np.round(self.range_m if self.range_m is not None else 0 * self.freq_hz, 4),
                            np.round(self.freq_hz)], 1)
            self.curve_id = np.unique(key, axis=0, return_inverse=True)[1].reshape(-1)
        else:
            self.curve_id = None

    @property
    def num(self) -> int:
        return len(self.pred_db)

    @property
    def residual_db(self) -> np.ndarray:
        """measured - predicted [dB]."""
        return self.meas_db - self.pred_db

    def elevation_rad(self) -> np.ndarray:
        """Elevation of the Rx seen from the Tx [rad] (0 for monostatic rows)."""
        d = self.rx_m - self.tx_m
        return np.arctan2(d[:, 2], np.maximum(np.linalg.norm(d[:, :2], axis=1), 1e-9))

    def reference_power(self) -> np.ndarray:
        """A smooth reference level per row [linear path gain]: free space (lambda / 4 pi d)^2 for
        links, and the radar equation's lambda^2 / ((4 pi)^3 R^4) (1 m^2, isotropic) for monostatic rows.
        Effects that add power scale it by a fitted factor."""
        lam = self.wavelength_m
        if self.monostatic:
            return lam**2 / ((4 * np.pi) ** 3 * self.dist_m**4)
        return (lam / (4 * np.pi * self.dist_m)) ** 2
