"""Train/test protocols (rf_fit.split) and the validation rows model selection holds out (stages/rf_fit/splits.py)."""
import numpy as np
import pytest

from rfir_cli.errors import ConfigError, StageError
from rfir_stages.rf_fit.splits import (KFOLD_MAX_LINKS, MIN_VALIDATION_LINKS, protocol_masks, split_rows,
                                       validation_folds, validation_rows)


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


def test_validation_rows_are_shaped_like_the_protocols_test():
    meas = _turntable()
    train, _ = split_rows(meas, "sector:45:135", "m.h5")
    deg = np.degrees(meas["aspect_rad"][train])
    val, how = validation_rows("sector:45:135", deg, meas["range_m"][train])
    got = np.sort(np.round(deg[val]).astype(int))
    assert len(val) == 27 and "next to the sector" in how                   # a tenth of 270 rows
    assert set(got) <= set(range(135, 150)) | set(range(30, 45))           # on both sides of the gap
    assert {135, 44} <= set(got)
    multi = _turntable(10.0, (2.0, 2.5, 3.0, 4.0))
    train, _ = split_rows(multi, "range:3", "m.h5")
    val, how = validation_rows("range:3", np.degrees(multi["aspect_rad"][train]), multi["range_m"][train])
    assert np.all(multi["range_m"][train][val] == 2.5) and len(val) == 36 and "2.5 m" in how
    val, how = validation_rows("every-10", np.arange(36.0) * 10, np.full(36, 3.0))
    assert np.array_equal(val, [5, 15, 25, 35]) and "every 10th" in how


def test_validation_folds_hold_out_enough_links_when_they_can():
    m = 36                                   # every 10th row: 4 links; 3 interleaved folds: all 36
    folds, how = validation_folds("data", np.arange(m) * 10.0, np.full(m, 3.0))
    assert len(folds) == 3 and sorted(np.concatenate(folds).tolist()) == list(range(m)) and "3-fold" in how
    big = 10 * MIN_VALIDATION_LINKS          # every 10th row is enough: one fold
    folds, _ = validation_folds("every-2", np.arange(big) * 0.5, np.full(big, 3.0))
    assert len(folds) == 1 and len(folds[0]) == MIN_VALIDATION_LINKS
    mid = KFOLD_MAX_LINKS + 30               # too many for k-fold: a larger share, every 3rd row
    folds, _ = validation_folds("data", np.arange(mid) * 1.0, np.full(mid, 3.0))
    assert len(folds) == 1 and len(folds[0]) == mid // 3
    rng = np.repeat([2.0, 3.0, 4.0], 12)     # range protocol: each training range in turn
    folds, how = validation_folds("range:5", np.tile(np.arange(12) * 30.0, 3), rng)
    assert [sorted(set(rng[f])) for f in folds] == [[2.0], [3.0], [4.0]]
    deg = np.arange(0, 360, 4.0)
    deg = deg[(deg < 45) | (deg >= 135)]     # sector:45:135 held out; the rows next to it validate
    folds, _ = validation_folds("sector:45:135", deg, np.full(len(deg), 3.0))
    near = deg[folds[0]]
    assert len(folds) == 1 and len(near) == min(MIN_VALIDATION_LINKS, len(deg) // 3)
    gap = np.minimum(np.mod(deg - 135, 360), np.mod(45 - deg, 360))
    assert gap[folds[0]].max() <= np.sort(gap)[len(near) - 1]
