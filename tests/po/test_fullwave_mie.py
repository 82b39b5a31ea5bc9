"""The Mie series of a PEC sphere (the closed form that validates the full-wave BEM solver)."""
from __future__ import annotations

import numpy as np
import pytest

from rfir_stages.fullwave import mie_pec_sphere_rcs
from rfir_stages.fullwave.mie import C0


def norm_rcs(ka: float, radius: float = 1.0) -> float:
    """sigma / (pi a^2) at size parameter ka."""
    return mie_pec_sphere_rcs(radius, ka * C0 / (2 * np.pi * radius)) / (np.pi * radius**2)


@pytest.mark.parametrize("ka", [0.01, 0.03])
def test_rayleigh_limit(ka):
    # sigma -> 9 pi a^2 (ka)^4; the next term is O((ka)^2) relative (about -0.2 (ka)^2)
    assert norm_rcs(ka) / (9 * ka**4) == pytest.approx(1.0, abs=0.5 * ka**2 + 1e-9)


def test_rayleigh_correction_is_second_order():
    # doubling ka quadruples the relative deviation from 9 (ka)^4: a wrong series would not
    d1 = 1 - norm_rcs(0.02) / (9 * 0.02**4)
    d2 = 1 - norm_rcs(0.04) / (9 * 0.04**4)
    assert d1 > 0 and d2 / d1 == pytest.approx(4.0, rel=0.02)


def test_optical_limit():
    # pi a^2 with a creeping-wave ripple that dies out as ka grows
    kas = np.linspace(50.0, 100.0, 201)
    v = np.array([norm_rcs(k) for k in kas])
    assert abs(v.mean() - 1.0) < 2e-3
    assert np.max(np.abs(10 * np.log10(v))) < 0.05
    assert abs(10 * np.log10(norm_rcs(500.0))) < 1e-3


def test_first_resonance_peak():
    # the textbook resonance-region maximum: sigma = 3.65 pi a^2 near ka = 1
    kas = np.linspace(0.5, 2.0, 601)
    v = np.array([norm_rcs(k) for k in kas])
    assert v.max() == pytest.approx(3.65, abs=0.02)
    assert kas[v.argmax()] == pytest.approx(1.03, abs=0.02)


def test_scales_with_radius():
    # the same ka on a sphere twice as large: sigma four times as large
    f = 1.0e9
    assert mie_pec_sphere_rcs(0.2, f / 2) == pytest.approx(4 * mie_pec_sphere_rcs(0.1, f), rel=1e-12)


def test_rejects_bad_size():
    with pytest.raises(ValueError):
        mie_pec_sphere_rcs(0.0, 1e9)
