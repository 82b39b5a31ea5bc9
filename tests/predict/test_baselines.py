"""Baselines for RCS versus aspect (nearest training aspect, linear interpolation)."""
import math

import numpy as np

from rfir_stages.predict.baselines import aspect_baselines

DEG = math.pi / 180


def test_baselines_on_a_known_curve():
    asp = np.arange(0, 360, 10) * DEG
    vals = np.sin(asp)[:, None] * 10
    train, test = np.arange(0, 36, 2), np.arange(1, 36, 2)
    out = aspect_baselines(asp, np.ones(36), vals, train, test)
    lin_expect = 0.5 * (vals[test - 1] + vals[(test + 1) % 36])
    np.testing.assert_allclose(out["linear"], lin_expect, atol=1e-9)
    # nearest: equidistant neighbours, either is right
    lo, hi = vals[test - 1], vals[(test + 1) % 36]
    assert np.all((np.abs(out["nearest"] - lo) < 1e-9) | (np.abs(out["nearest"] - hi) < 1e-9))
    near = aspect_baselines(asp, np.ones(36), vals, train, np.array([1]))["nearest"]
    assert near.shape == (1, 1)


def test_range_baselines():
    from rfir_stages.predict.baselines import range_baselines

    asp = np.tile(np.array([0.0, 1.0]), 3)
    rng = np.repeat([2.0, 3.0, 4.0], 2)
    vals = (10 * rng + asp)[:, None]
    train, test = np.array([0, 1, 4, 5]), np.array([2, 3])
    out = range_baselines(asp, rng, vals, train, test)
    np.testing.assert_allclose(out["linear_range"][:, 0], [30.0, 31.0])
    assert set(out["nearest_range"][:, 0]) <= {20.0, 21.0, 40.0, 41.0}
