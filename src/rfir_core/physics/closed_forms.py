"""Closed forms that every radio model in rfir is checked against.

Conventions: exp(+j 2 pi f t) time dependence, propagation multiplies the field by exp(-j k d),
c = 299 792 458 m/s exactly (3e8 leaves a 0.006 dB offset against Sionna).
"""
from __future__ import annotations

import numpy as np

C0 = 299_792_458.0


def wavelength_m(freq_hz):
    """lambda = c / f [m]."""
    return C0 / np.asarray(freq_hz, dtype=float)


def wavenumber(freq_hz):
    """k = 2 pi f / c [rad/m]."""
    return 2.0 * np.pi * np.asarray(freq_hz, dtype=float) / C0


def power_to_db(ratio):
    """10 log10 of a power ratio."""
    return 10.0 * np.log10(ratio)


def db_to_power(value_db):
    """Inverse of power_to_db."""
    return 10.0 ** (np.asarray(value_db, dtype=float) / 10.0)


def friis_path_gain(distance_m, freq_hz, gain_tx: float = 1.0, gain_rx: float = 1.0):
    """Free-space P_R / P_T = G_T G_R (lambda / (4 pi d))^2."""
    return gain_tx * gain_rx * (wavelength_m(freq_hz) / (4.0 * np.pi * np.asarray(distance_m, dtype=float))) ** 2


def plate_image_echo_gain(range_m, freq_hz):
    """Monostatic echo of an infinite perfectly conducting plate at normal incidence: (lambda / (8 pi r))^2.

    The image source sits at 2 r, so this is Friis over 2 r with |Gamma| = 1 and isotropic antennas.
    """
    return (wavelength_m(freq_hz) / (8.0 * np.pi * np.asarray(range_m, dtype=float))) ** 2


def rcs_from_path_gain(path_gain, range_m, freq_hz, gain_tx: float = 1.0, gain_rx: float = 1.0):
    """Monostatic radar equation solved for sigma [m^2]: (4 pi)^3 r^4 P_R / (P_T G_T G_R lambda^2)."""
    r = np.asarray(range_m, dtype=float)
    return (4.0 * np.pi) ** 3 * r**4 * np.asarray(path_gain) / (gain_tx * gain_rx * wavelength_m(freq_hz) ** 2)


def plate_rcs_broadside_m2(area_m2, freq_hz):
    """Far-field broadside RCS of a flat conducting plate: 4 pi A^2 / lambda^2."""
    return 4.0 * np.pi * np.asarray(area_m2, dtype=float) ** 2 / wavelength_m(freq_hz) ** 2


def sphere_rcs_m2(radius_m):
    """Optical-region RCS of a conducting sphere (radius >> lambda): pi a^2."""
    return np.pi * np.asarray(radius_m, dtype=float) ** 2


def cylinder_rcs_broadside_m2(radius_m, length_m, freq_hz):
    """Far-field broadside RCS of a conducting circular cylinder (k a >> 1, length >> lambda), the
    stationary-phase result of physical optics: 2 pi a L^2 / lambda."""
    return 2.0 * np.pi * np.asarray(radius_m, dtype=float) * np.asarray(length_m, dtype=float) ** 2 / wavelength_m(freq_hz)
