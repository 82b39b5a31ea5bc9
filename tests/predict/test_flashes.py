"""Flashes on test rows (stages/predict/flashes.py): synthetic RCS curves with peaks of known height and aspect."""
import json
import math

import numpy as np

from rfir_stages.predict.flashes import find_flashes, flash_defaults, score_flashes
from rfir_stages.predict.rcs import _flashes

ASPECT_DEG = np.arange(360.0)
FLOOR_DBSM = -20.0
PEAK_DBSM = 14.0
LOBE_DEG = 5.0   # first null of the sinc^2 lobe, deg from its centre


def lobe_curve(centre_deg: float) -> np.ndarray:
    """dBsm [360]: a floor plus the main lobe of a sinc^2 (a plate's broadside flash) peaking at PEAK_DBSM."""
    d = np.mod(ASPECT_DEG - centre_deg + 180.0, 360.0) - 180.0
    x = d / LOBE_DEG
    floor = 10 ** (FLOOR_DBSM / 10)
    lobe = (10 ** (PEAK_DBSM / 10) - floor) * np.sinc(x) ** 2 * (np.abs(x) < 1)
    return 10 * np.log10(floor + lobe)


def score(measured, test, predictions, **kw):
    cfg = {"min_prominence_db": 10.0, "window_deg": 3.0, "tolerance_db": 3.0} | kw
    measured = np.asarray(measured)[:, None]
    return score_flashes(np.radians(ASPECT_DEG), np.full(360, 3.0), np.array([2.4e9]), measured, test,
                         {k: np.asarray(v)[:, None] for k, v in predictions.items()}, **cfg)


def sector(a, b):
    return (ASPECT_DEG >= a) & (ASPECT_DEG < b)


def test_a_lobe_in_a_held_out_sector_is_one_flash_of_known_height():
    m = lobe_curve(100.0)
    rep = score(m, sector(45, 135), {"exact": m, "shifted_2deg": np.roll(m, 2), "low_10db": m - 10.0,
                                    "shifted_6deg": np.roll(m, 6)})
    assert rep["num_flashes"] == 1
    f = rep["flashes"][0]
    assert f["aspect_deg"] == 100.0
    assert abs(f["measured_dbsm"] - PEAK_DBSM) < 1e-9
    assert abs(f["prominence_db"] - (PEAK_DBSM - FLOOR_DBSM)) < 1e-9
    assert abs(f["error_db"]["exact"]) < 1e-9
    assert abs(f["error_db"]["shifted_2deg"]) < 1e-9          # a 2-degree glint shift lies in the window
    assert abs(f["error_db"]["low_10db"] + 10.0) < 1e-9
    # 6 degrees off: the best inside +-3 deg is the lobe 3 deg from its centre, sinc^2(0.6): 5.9 dB low
    expect = 10 * math.log10(10 ** (FLOOR_DBSM / 10) + (10 ** (PEAK_DBSM / 10) - 10 ** (FLOOR_DBSM / 10))
                             * np.sinc(0.6) ** 2)
    assert abs(f["predicted_dbsm"]["shifted_6deg"] - expect) < 1e-9
    within = {k: v["num_within_tolerance"] for k, v in rep["methods"].items()}
    assert within == {"exact": 1, "shifted_2deg": 1, "low_10db": 0, "shifted_6deg": 0}
    assert rep["methods"]["low_10db"]["median_abs_error_db"] == 10.0


def test_a_flash_on_a_training_row_and_a_weak_bump_are_not_counted():
    m = lobe_curve(100.0)
    every_10_trains = np.mod(ASPECT_DEG, 10) != 0                       # 100 deg is a training row
    rep = score(m, every_10_trains, {"rfir": m})
    assert rep["num_flashes"] == 0 and rep["curves"][0]["num_flashes"] == 0
    assert rep["methods"]["rfir"] == {"num_predicted": 0, "num_within_tolerance": 0, "median_abs_error_db": None}
    bump = 3.0 * np.cos(np.radians(4 * ASPECT_DEG))                      # 6 dB peak to trough: no flash
    rep = score(bump, np.ones(360, bool), {"rfir": bump})
    assert rep["num_flashes"] == 0
    json.dumps(rep, allow_nan=False)                                     # never NaN in the results JSON
    # the same bump at twice the depth has four flashes, each 12 dB prominent
    rep = score(2 * bump, np.ones(360, bool), {"rfir": 2 * bump})
    assert [f["aspect_deg"] for f in rep["flashes"]] == [0.0, 90.0, 180.0, 270.0]


def test_a_flash_across_the_seam_at_359_to_0_deg():
    m = lobe_curve(0.0)
    test = sector(350, 360) | sector(0, 10)
    idx, prom = find_flashes(ASPECT_DEG, m, 10.0)
    assert idx.tolist() == [0] and abs(prom[0] - (PEAK_DBSM - FLOOR_DBSM)) < 1e-9
    rep = score(m, test, {"shifted_to_358": np.roll(m, -2), "shifted_to_2": np.roll(m, 2)})
    assert rep["num_flashes"] == 1 and rep["flashes"][0]["aspect_deg"] == 0.0
    assert rep["methods"]["shifted_to_358"]["num_within_tolerance"] == 1   # the window wraps too
    assert rep["methods"]["shifted_to_2"]["num_within_tolerance"] == 1
    # a half-circle of aspects is not circular: its end is not a peak
    assert find_flashes(ASPECT_DEG[:180], m[:180], 10.0)[0].size == 0


def test_predict_rcs_scores_the_baselines_on_the_same_flashes():
    """_flashes (predict rcs' results JSON): nearest and linear interpolation from the training edges of a
    held-out sector cannot see a flash inside it; a prediction equal to the measurement does."""
    m = lobe_curve(100.0)[:, None].repeat(2, axis=1)
    m[:, 1] = lobe_curve(300.0)                                          # second frequency: flash on a training row
    split = np.where(sector(45, 135), 1, 0)
    rep = _flashes({}, m, None, m, split, np.radians(ASPECT_DEG), np.full(360, 3.0), np.array([2.4e9, 5.8e9]))
    assert rep["window_deg"] == flash_defaults()["window_deg"]
    assert [c["num_flashes"] for c in rep["curves"]] == [1, 0]
    assert set(rep["methods"]) == {"rfir", "nearest", "linear"}         # range baselines: no other range trains
    assert rep["methods"]["rfir"]["num_within_tolerance"] == 1
    for name in ("nearest", "linear"):
        assert rep["methods"][name]["num_within_tolerance"] == 0
        assert abs(rep["flashes"][0]["error_db"][name] - (FLOOR_DBSM - PEAK_DBSM)) < 1e-9
