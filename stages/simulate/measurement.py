"""Measurement effects added after the simulation (so a "measured" set can hold what a model lacks)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MeasurementEffects:
    """noise_db: std of Gaussian noise on path gain (dB); gain_offset_db: constant offset (dB);
    ripple_db, ripple_period_hz: ripple_db * sin(2 pi (f - f_min) / period) (dB);
    floor_db: path gains below are clipped to it (dB)."""

    noise_db: float = 0.0
    gain_offset_db: float = 0.0
    ripple_db: float = 0.0
    ripple_period_hz: float = 40e6
    floor_db: float = -250.0


def ripple_db(freq_hz, effects: MeasurementEffects) -> np.ndarray:
    f = np.asarray(freq_hz, dtype=np.float64)
    if effects.ripple_db == 0.0 or effects.ripple_period_hz <= 0:
        return np.zeros_like(f)
    return effects.ripple_db * np.sin(2 * math.pi * (f - f.min()) / effects.ripple_period_hz)


def apply_measurement_effects(power_lin, channel, freq_hz, effects: MeasurementEffects, rng: np.random.Generator):
    """Return (path_gain_db (L, F), channel (L, F)) with the effects applied.

    The complex channel is scaled by the same dB change as the power, keeping its phase, so
    |channel|^2 = 10^(path_gain_db / 10) still holds (except where the floor clips a zero channel,
    which then gets the floor's magnitude with zero phase).
    """
    power = np.asarray(power_lin, dtype=np.float64)
    clean_db = 10.0 * np.log10(np.maximum(power, 1e-300))
    delta = np.full(power.shape, float(effects.gain_offset_db))
    delta += ripple_db(freq_hz, effects)[None, :]
    if effects.noise_db > 0:
        delta += rng.normal(0.0, effects.noise_db, power.shape)
    gain_db = np.maximum(clean_db + delta, effects.floor_db)
    mag = np.abs(channel)
    unit = np.where(mag > 0, channel / np.maximum(mag, 1e-300), 1.0 + 0j)
    return gain_db, unit * 10 ** (gain_db / 20.0)
