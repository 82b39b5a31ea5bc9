"""Monostatic radar cross section of a perfectly conducting sphere: the Mie series (closed form).

    sigma = (lambda^2 / (4 pi)) |sum_{n>=1} (-1)^n (2n+1) (a_n - b_n)|^2
    a_n = j_n(x) / h_n(x),  b_n = [x j_n(x)]' / [x h_n(x)]',  x = k a

j_n, h_n = j_n + i y_n are spherical Bessel and Hankel functions (the Hankel kind only conjugates the
sum, |.|^2 is the same). Limits: Rayleigh sigma -> 9 pi a^2 (ka)^4 for ka << 1; optical sigma -> pi a^2.
"""
from __future__ import annotations

import numpy as np
from scipy.special import spherical_jn, spherical_yn

C0 = 299_792_458.0  # m/s


def mie_pec_sphere_rcs(radius_m: float, freq_hz: float) -> float:
    """Monostatic RCS [m^2] of a PEC sphere of radius `radius_m` [m] at `freq_hz` [Hz]."""
    x = 2.0 * np.pi * float(freq_hz) / C0 * float(radius_m)
    if not x > 0:
        raise ValueError(f"ka must be positive, got {x}")
    # Wiscombe's truncation: terms beyond x + 4 x^(1/3) + 2 are below double precision
    n = np.arange(1, int(x + 4.0 * x ** (1.0 / 3.0) + 3))
    j, jd = spherical_jn(n, x), spherical_jn(n, x, derivative=True)
    h = j + 1j * spherical_yn(n, x)
    hd = jd + 1j * spherical_yn(n, x, derivative=True)
    a = j / h
    b = (j + x * jd) / (h + x * hd)  # [x f(x)]' = f + x f'
    total = np.sum((-1.0) ** n * (2 * n + 1) * (a - b))
    lam = C0 / float(freq_hz)
    return float(lam * lam / (4.0 * np.pi) * abs(total) ** 2)
