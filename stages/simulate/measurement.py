"""Measurement effects added after the simulation (so a "measured" set can hold what a model lacks)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class MeasurementEffects:
    """noise_db: std of Gaussian noise on path gain (dB); gain_offset_db: constant offset (dB);
    ripple_db, ripple_period_hz: ripple_db * sin(2 pi (f - f_min) / period) (dB);
    floor_db: path gains below are clipped to it (dB);
    noise_floor_db: receiver noise power added to every path gain (dB; -250: none);
    saturation_db: path gains above are clipped to it (dB; 250: none);
    leakage_db, leakage_phase_deg: a direct Tx-Rx coupling 10^(leakage_db/20) e^(j phase) added to the
    complex channel before the other effects (dB; -250: none; the monostatic radar's leakage);
    aspect_offset_deg: the turntable's recorded aspect (and radar position) is off by this (deg)."""

    noise_db: float = 0.0
    gain_offset_db: float = 0.0
    ripple_db: float = 0.0
    ripple_period_hz: float = 40e6
    floor_db: float = -250.0
    noise_floor_db: float = -250.0
    saturation_db: float = 250.0
    leakage_db: float = -250.0
    leakage_phase_deg: float = 0.0
    aspect_offset_deg: float = 0.0


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
    if effects.leakage_db > -250.0:   # coherent: the coupling interferes with the scene's echo
        leaked = np.asarray(channel) + 10 ** (effects.leakage_db / 20.0) * np.exp(1j * math.radians(
            effects.leakage_phase_deg))
        # the incoherent part of a power-combined simulation stays; the coherent part interferes
        power = np.maximum(power - np.abs(channel) ** 2, 0.0) + np.abs(leaked) ** 2
        channel = leaked
    if effects.noise_floor_db > -250.0:
        power = power + 10 ** (effects.noise_floor_db / 10.0)
    clean_db = 10.0 * np.log10(np.maximum(power, 1e-300))
    delta = np.full(power.shape, float(effects.gain_offset_db))
    delta += ripple_db(freq_hz, effects)[None, :]
    if effects.noise_db > 0:
        delta += rng.normal(0.0, effects.noise_db, power.shape)
    gain_db = np.clip(clean_db + delta, effects.floor_db, effects.saturation_db)
    mag = np.abs(channel)
    unit = np.where(mag > 0, channel / np.maximum(mag, 1e-300), 1.0 + 0j)
    return gain_db, unit * 10 ** (gain_db / 20.0)
