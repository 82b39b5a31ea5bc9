"""Closed forms agree with each other where physics says they must."""
import numpy as np

from rfir_core.physics import (C0, friis_path_gain, plate_image_echo_gain, plate_rcs_broadside_m2, power_to_db,
                              rcs_from_path_gain, sphere_rcs_m2, wavelength_m)


def test_friis_inverse_square_and_value():
    f = 2.4e9
    g1, g2 = friis_path_gain(1.0, f), friis_path_gain(10.0, f)
    assert abs(power_to_db(g1 / g2) - 20.0) < 1e-12
    assert abs(power_to_db(g1) - (-40.046)) < 1e-2       # the textbook 40 dB at 1 m, 2.4 GHz


def test_plate_echo_is_friis_over_twice_the_range():
    r, f = np.array([2.0, 3.0, 5.0]), 5.8e9
    np.testing.assert_allclose(plate_image_echo_gain(r, f), friis_path_gain(2 * r, f))


def test_radar_equation_round_trip():
    sigma, r, f = 0.3, 4.0, 2.4e9
    lam = C0 / f
    path_gain = sigma * lam**2 / ((4 * np.pi) ** 3 * r**4)
    assert np.isclose(rcs_from_path_gain(path_gain, r, f), sigma)
    assert np.isclose(wavelength_m(f), lam)


def test_plate_and_sphere_rcs():
    lam = wavelength_m(2.4e9)
    assert np.isclose(plate_rcs_broadside_m2(0.25, 2.4e9), 4 * np.pi * 0.0625 / lam**2)
    assert np.isclose(sphere_rcs_m2(0.5), np.pi / 4)
