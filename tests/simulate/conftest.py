"""Shared checks for simulate's tests."""
import math

import numpy as np
import pytest


def check_quick_rcs_conventions(art, scene: str = "lego") -> None:
    """The RCS artifact conventions every backend must share (quick lego: 8 aspects x 2 ranges x 2 freqs).

    Radar at azimuth -aspect at the stated range, Tx 2 mm above Rx, even aspect steps train and odd
    test, |channel|^2 equal to the path gain.
    """
    d = art.data
    assert art.attrs["task"] == "rcs" and art.attrs["scene"] == scene
    assert d["path_gain_db"].shape == (16, 2) and d["rcs_dbsm"].shape == (16, 2) and d["channel"].dtype.kind == "c"
    np.testing.assert_allclose(d["freq_hz"], [2.4e9, 5.8e9])
    mid = 0.5 * (d["tx_pos"] + d["rx_pos"])
    np.testing.assert_allclose(np.linalg.norm(mid, axis=1), d["range_m"], atol=1e-9)
    np.testing.assert_allclose(np.arctan2(mid[:, 1], mid[:, 0]) % (2 * math.pi),
                               (-d["aspect_rad"]) % (2 * math.pi), atol=1e-9)
    np.testing.assert_allclose(d["tx_pos"][:, 2] - d["rx_pos"][:, 2], 0.002)
    assert d["split"].tolist() == [0, 1] * 8
    np.testing.assert_allclose(np.abs(d["channel"]) ** 2, 10 ** (d["path_gain_db"] / 10), rtol=1e-9)
    assert np.isfinite(d["rcs_dbsm"]).all() and (d["rcs_dbsm"] > -80).all()


@pytest.fixture(name="check_quick_rcs_conventions")
def check_quick_rcs_conventions_fixture():
    return check_quick_rcs_conventions
