"""The effects added for device calibration, losses, dynamic range and obstacles, hidden in synthetic rows
(0.5 dB noise): each is named with its parameters, the held-out gap shrinks, and pairs are named both."""
import numpy as np
import pytest

from rfir_stages.diagnose.obstacle import segments_cross_boxes
from rfir_stages.diagnose.select import choose, compose, evaluate, search

from .test_select import room_rows

NOISE_DB = 0.5


def _noisy(rows, correction, seed=1):
    rows.meas_db = rows.pred_db + correction + np.random.default_rng(seed).normal(0, NOISE_DB, rows.num)
    return rows


def _name_all(rows, max_effects=3):
    """The chain diagnose builds: name (one effect or a pair), add, refit, repeat."""
    return search(rows, max_effects)[0]


def _heldout_mae(rows, pred):
    return float(np.mean(np.abs(rows.meas_db - pred)[rows.test]))


@pytest.mark.parametrize("db", [-5.0, 4.0])
def test_a_loss_or_gain_per_crossing_of_either_sign(db):
    rows = room_rows()
    rows = _noisy(rows, db * rows.crossings)
    chain = _name_all(rows)
    assert [e.name for e, _ in chain] == ["crossing_loss"]
    assert abs(chain[0][1][0] - db) < 0.3
    assert _heldout_mae(rows, compose(chain, rows)) < 0.5


def test_per_transmitter_offsets():
    rows = room_rows()
    tx_ids = np.unique(rows.tx_m, axis=0, return_inverse=True)[1].reshape(-1)
    true = np.array([0.0, -4.0, 2.5, -1.5, 3.5, -6.0])
    rows = _noisy(rows, true[tx_ids])
    chain = _name_all(rows)
    assert chain[0][0].name == "tx_offsets", [e.name for e, _ in chain]
    fitted = chain[0][1][:6]
    got = fitted - fitted.mean()
    assert np.allclose(got, true - true.mean(), atol=0.3), got
    assert _heldout_mae(rows, compose(chain, rows)) < 0.5


def test_per_receiver_offsets():
    rows = room_rows()
    rx_ids = np.unique(rows.rx_m, axis=0, return_inverse=True)[1].reshape(-1)
    true = np.random.default_rng(3).normal(0, 3.0, rx_ids.max() + 1)
    rows = _noisy(rows, true[rx_ids])
    best, _ = choose(evaluate(rows, rows.pred_db))
    assert best is not None and best.name == "rx_offsets"
    assert best.test_mae_db < 0.4 * best.mae_before_db


def test_a_single_common_offset_is_a_gain_not_device_offsets():
    rows = _noisy(room_rows(), np.full(room_rows().num, -3.0))
    best, _ = choose(evaluate(rows, rows.pred_db))
    assert best.name == "gain_offset"


def test_a_dynamic_range_floor():
    rows = room_rows()
    floor = float(np.quantile(rows.pred_db, 0.25))
    rows = _noisy(rows, np.maximum(rows.pred_db, floor) - rows.pred_db)
    chain = _name_all(rows)
    assert [e.name for e, _ in chain][:1] == ["dynamic_range"], [e.name for e, _ in chain]
    assert abs(chain[0][1][0] - floor) < 1.0


def test_an_obstacle_is_boxed_on_the_floor_plan():
    rows = room_rows()
    box = np.array([5.5, 3.0, 7.0, 4.2])
    hit = segments_cross_boxes(rows.tx_m[:, :2], rows.rx_m[:, :2], box[None])[:, 0]
    rows = _noisy(rows, -8.0 * hit)
    chain = _name_all(rows)
    assert chain and chain[0][0].name == "obstacle", [e.name for e, _ in chain]
    x = chain[0][1]
    assert abs(x[0] + 8.0) < 1.0
    assert np.all(np.abs(x[1:] - box) < 0.8), x[1:]
    assert _heldout_mae(rows, compose(chain, rows)) < 0.6


def test_segment_box_crossing():
    p0 = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 2.0], [1.5, 1.5]])
    p1 = np.array([[3.0, 3.0], [3.0, 0.0], [3.0, 2.0], [5.0, 5.0]])
    got = segments_cross_boxes(p0, p1, np.array([[1.0, 1.0, 2.0, 2.0]]))[:, 0]
    assert got.tolist() == [True, False, True, True]    # diagonal through, passes below, along the edge, starts inside


def test_gain_and_noise_floor_are_both_named():
    rows = room_rows()
    floor = float(np.quantile(rows.pred_db, 0.3)) - 3.0
    lin = 10 ** ((rows.pred_db - 4.0) / 10) + 10 ** (floor / 10)
    rows = _noisy(rows, 10 * np.log10(lin) - rows.pred_db)
    chain = _name_all(rows)
    assert {e.name for e, _ in chain} == {"gain_offset", "noise_floor"}, [e.name for e, _ in chain]
    assert _heldout_mae(rows, compose(chain, rows)) < 0.5


def test_noise_alone_names_none_of_the_flexible_effects():
    rows = _noisy(room_rows(), 0.0, seed=9)
    cands = {c.name: c for c in evaluate(rows, rows.pred_db)}
    for name in ("tx_offsets", "rx_offsets", "obstacle", "crossing_loss", "dynamic_range"):
        assert cands[name].applies and not cands[name].significant, (name, cands[name].score)


def test_structure_outside_the_catalogue_leads_the_headline():
    from rfir_stages.diagnose.breakdown import analyse
    from rfir_stages.diagnose.stage import headline, lacking_structure

    rows = room_rows()
    d = rows.dist_m
    rows = _noisy(rows, np.where((d > 3.0) & (d < 5.0), -6.0, 0.0))   # a bump in distance: no effect has it
    chain, _steps, named, ambiguous = search(rows, 2)
    lacking = lacking_structure(analyse(rows, compose(chain, rows)), "residual_after.png")
    text = headline(named, ambiguous, lacking)
    assert text.startswith("structure the model lacks, not in the catalogue: by ") and "range" in text, text
    assert named == []   # the flexible stand-ins (a ground bounce, a clip) reproduce too little of it
    pure = _noisy(room_rows(), 0.0, seed=4)
    assert headline([], [], lacking_structure(analyse(pure, pure.pred_db), "x.png")).startswith("no missing effect")


def test_absent_phases_are_absent():
    from rfir_stages.diagnose.data import measured_phases

    assert measured_phases(None, "f")[0] is None
    assert "placeholders" in measured_phases(np.array([1.0, 2.0, 0.5]) + 0j, "f")[1]
    assert "lacks the phase on 1 of 3" in measured_phases(np.array([1j, np.nan, 1.0]), "f")[1]
    h = np.exp(1j * np.array([0.3, -1.0, 2.0]))
    assert measured_phases(h, "f") == (h, "measured") or measured_phases(h, "f")[1] == "measured"


def test_the_leakage_phase_is_reported_in_degrees():
    from rfir_stages.diagnose.effects import BY_NAME

    from .test_select import radar_rows

    rows = radar_rows()
    rows.pred_channel = rows.meas_channel.copy()
    leak = 10 ** (-78 / 20) * np.exp(1j * np.radians(60.0))
    rows.meas_channel = rows.meas_channel + leak
    rows.meas_db = 10 * np.log10(np.abs(rows.meas_channel) ** 2)
    chain, steps, named, _ = search(rows, 1)
    assert named[0]["effect"] == "leakage"
    assert abs(steps[0]["params"]["phase_deg"] - 60.0) < 2.0 and abs(named[0]["params"]["phase_deg"] - 60.0) < 2.0
    assert BY_NAME["leakage"].needs_phase
