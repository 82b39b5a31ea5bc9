"""The validation folds model selection holds out (stages/model/validation_folds.py), shaped like the protocol's test."""
import numpy as np

from rfir_stages.model.split_protocols import split_rows
from rfir_stages.model.validation_folds import KFOLD_MAX_LINKS, MIN_VALIDATION_LINKS, validation_folds, validation_rows

from .test_splits import _turntable


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
    m = 36                                   # every 10th row: 4 links; 3 folds: all 36
    folds, how = validation_folds("data", np.arange(m) * 10.0, np.full(m, 3.0))
    assert len(folds) == 3 and sorted(np.concatenate(folds).tolist()) == list(range(m)) and "3-fold" in how
    assert sorted(len(f) for f in folds) == [12, 12, 12]
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


def test_kfold_folds_hold_whole_aspects_and_do_not_line_up_with_a_symmetry():
    """12 aspects 30 degrees apart at 3 ranges: every range of an aspect in one fold; the four broadsides
    of a box (0, 90, 180, 270 degrees), which every 3rd aspect in turn would put in one fold, are spread."""
    deg = np.repeat(np.arange(12) * 30.0, 3)
    rng = np.tile([2.0, 3.0, 4.0], 12)
    folds, how = validation_folds("every-30", deg, rng)
    assert len(folds) == 3 and sorted(np.concatenate(folds).tolist()) == list(range(36)) and "aspects" in how
    for f in folds:
        assert np.all(np.isin(deg, deg[f]) == np.isin(np.arange(36), f))      # whole aspects
        assert len(set(deg[f]) & {0.0, 90.0, 180.0, 270.0}) < 4
    again, _ = validation_folds("every-30", deg, rng)
    assert all(np.array_equal(a, b) for a, b in zip(folds, again))            # a fixed deal
