"""Train/test protocols (rf_fit.split, stages/model/split_protocols.py)."""
import numpy as np
import pytest

from rfir_core.errors import ConfigError, StageError
from rfir_stages.model.split_protocols import protocol_masks, split_rows


def _turntable(step_deg=1.0, ranges=(3.0,)):
    asp = np.radians(np.arange(0.0, 360.0, step_deg))
    a, r = np.meshgrid(asp, np.asarray(ranges, float), indexing="xy")
    split = (np.round(np.degrees(a)).astype(int) % 2).reshape(-1)
    return {"aspect_rad": a.reshape(-1), "range_m": r.reshape(-1), "split": split, "tx_pos": np.zeros((a.size, 3))}


def test_split_protocols_select_the_documented_rows():
    meas = _turntable()
    train, test = split_rows(meas, "every-10", "m.h5")
    assert len(train) == 36 and len(test) == 324
    assert np.all(np.round(np.degrees(meas["aspect_rad"][train])) % 10 == 0)
    train, test = split_rows(meas, "sector:315:45", "m.h5")          # wraps through 0
    deg = np.degrees(meas["aspect_rad"][test])
    assert len(test) == 90 and np.all((deg >= 315) | (deg < 45))
    train, test = split_rows(meas, "data", "m.h5")
    assert np.array_equal(train, np.flatnonzero(meas["split"] == 0))
    multi = _turntable(2.0, (2.0, 3.0, 4.0))
    train, test = split_rows(multi, "range:3", "m.h5")
    assert np.all(multi["range_m"][test] == 3.0) and not np.any(multi["range_m"][train] == 3.0)
    tr, te = protocol_masks(multi, "every-3", "m.h5")
    assert not np.any(tr & te) and np.all(tr | te)


@pytest.mark.parametrize("bad", ["every-1", "every-x", "sector:10", "lottery", "range:x"])
def test_unknown_or_malformed_protocols_are_config_errors(bad):
    with pytest.raises(ConfigError, match="split"):
        split_rows(_turntable(), bad, "m.h5")


def test_protocols_that_leave_nothing_are_refused():
    with pytest.raises(StageError, match="empty training split"):
        split_rows({**_turntable(), "split": np.ones(360, int)}, "data", "m.h5")
    with pytest.raises(StageError, match="holds out no row"):
        split_rows(_turntable(), "range:7", "m.h5")
