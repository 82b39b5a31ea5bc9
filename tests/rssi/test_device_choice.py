"""Device gains of measured data chosen by validation on held-out positions (stages/rf_fit/device_choice.py)."""
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact, write_artifact
from rfir_cli.main import app
from rfir_stages.model.device_gains import DeviceGains, device_index, gains_at, ridge_gains
from rfir_stages.rf_fit.device_choice import choose_device_gains

from .helpers import reference_gain_db, write_scene

TX = np.array([[0.7, 0.6, 2.0], [3.3, 0.6, 2.0], [0.7, 2.4, 2.0], [3.3, 2.4, 2.0]])
TX_GAIN_DB = np.array([2.0, -1.0, 0.5, -1.5])


def walk(num_rx=60, seed=1):
    """A walk survey: the 4 transmitters TX, one receiver carried to num_rx positions; (tx [M, 3], rx [M, 3],
    tx index [M], rx position index [M])."""
    rng = np.random.default_rng(seed)
    rx = np.column_stack([rng.uniform(0.3, 3.7, num_rx), rng.uniform(0.3, 2.7, num_rx), np.full(num_rx, 1.0)])
    ti, ri = np.repeat(np.arange(len(TX)), num_rx), np.tile(np.arange(num_rx), len(TX))
    return TX[ti], rx[ri], ti, ri


def _synthetic(tx_gain_db, position_db, noise_db=0.5, seed=2):
    """Targets = a known physical prediction + device terms; the stub 'fit' returns that prediction exactly."""
    tx, rx, ti, ri = walk()
    rng = np.random.default_rng(seed)
    physical = -40.0 - 20 * np.log10(np.linalg.norm(tx - rx, axis=1))
    per_position = rng.normal(0, position_db, ri.max() + 1)[ri]   # fading that looks like a per-position gain
    target = physical + np.asarray(tx_gain_db)[ti] + per_position + rng.normal(0, noise_db, len(ti))
    calls = []

    def fit(rows):
        calls.append(len(rows))
        return physical + target[rows].mean() - physical[rows].mean()   # the system gain fitted
    return tx, rx, ti, target, fit, calls


def test_transmitter_offsets_are_chosen_and_per_position_receiver_gains_are_not():
    tx, rx, ti, target, fit, calls = _synthetic(TX_GAIN_DB * 2, position_db=2.0)
    choice = choose_device_gains(tx, rx, {"tx": None, "rx": None}, target, 3.0, fit, seed=0)
    assert choice.which == "tx", choice
    assert choice.scores["tx"] < choice.scores["off"] - 0.5
    # a receiver gain per position carries to no held-out position: it scores as 'off' and is not taken
    assert abs(choice.scores["rx"] - choice.scores["off"]) < 1e-9
    assert calls == [192] and "validated on 48 training links" in choice.reason


def test_no_device_offsets_means_no_gains():
    tx, rx, ti, target, fit, _ = _synthetic(np.zeros(4), position_db=3.0)
    assert choose_device_gains(tx, rx, {"tx": None, "rx": None}, target, 3.0, fit, seed=0).which == "off"


def test_one_roaming_receiver_told_apart_by_id_is_one_device_and_no_candidate():
    tx, rx, ti, target, fit, _ = _synthetic(TX_GAIN_DB * 2, position_db=1.0)
    choice = choose_device_gains(tx, rx, {"tx": ti, "rx": np.zeros(len(ti), np.int64)}, target, 3.0, fit, seed=0)
    assert choice.which == "tx" and set(choice.scores) == {"off", "tx"}


def test_too_few_links_to_validate_leave_the_gains_off_and_say_why():
    tx, rx, ti, target, fit, calls = _synthetic(TX_GAIN_DB, position_db=1.0)
    rows = np.arange(0, len(ti), 20)
    choice = choose_device_gains(tx[rows], rx[rows], {"tx": None, "rx": None}, target[rows], 3.0,
                                 lambda r: target[rows], seed=0)
    assert choice.which == "off" and "too few links" in choice.reason


def test_ridge_gains_match_the_closed_form_per_device():
    r = np.concatenate([np.full(2, 3.0), np.full(5, -2.0), np.full(20, 1.0)])
    idx = np.repeat(np.arange(3), [2, 5, 20])
    lam = np.mean(r ** 2) / 2.0 ** 2
    got = ridge_gains(r, {"tx": idx}, 2.0)["tx"]
    np.testing.assert_allclose(got, [6 / (2 + lam), -10 / (5 + lam), 20 / (20 + lam)])


def test_devices_by_id_a_roaming_one_matches_every_position_and_fixed_ones_their_own():
    tx, rx, ti, ri = walk(num_rx=5)
    uniq, inv, pos = device_index(rx, np.zeros(len(rx), np.int64))
    assert len(uniq) == 1 and np.isnan(pos).all()
    dev = DeviceGains("both", tx, rx, 3.0, tx_id=ti + 10, rx_id=np.zeros(len(rx), np.int64))
    with np.errstate(all="ignore"):
        dev.gains["tx"].data[:] = dev.gains["tx"].data.new_tensor([1.0, 2.0, 3.0, 4.0])
        dev.gains["rx"].data[:] = 0.5
    table = dev.table()
    assert table["device_tx_id"].tolist() == [10, 11, 12, 13]
    got, matched = gains_at(table, np.array([TX[2], [9.0, 9, 9]]), np.array([[5.0, 5, 1], [1.0, 1, 1]]))
    np.testing.assert_allclose(got, [3.5, 0.5])       # the one receiver's gain applies anywhere; a new Tx none
    assert matched == 3


@pytest.fixture(scope="module")
def walk_survey(tmp_path_factory):
    """The reduced room measured as a walk survey with no device ids (told apart by position only), transmitter
    offsets and 1.5 dB of fading; the test rows are 12 of the 60 receiver positions."""
    d = tmp_path_factory.mktemp("walk")
    write_scene(d / "scene.h5", spacing_m=0.3)
    tx, rx, ti, ri = walk()
    rng = np.random.default_rng(3)
    gain = reference_gain_db(tx, rx, 2.4e9) + TX_GAIN_DB[ti] + rng.normal(0, 1.5, len(ti))
    split = np.isin(ri, rng.permutation(ri.max() + 1)[:12]).astype(np.int64)
    write_artifact(d / "meas.h5", "measurements", {"tx_pos": tx, "rx_pos": rx, "freq_hz": np.array([2.4e9]),
                                                   "path_gain_db": gain[:, None], "split": split},
                   attrs={"task": "rssi", "scene": "walk"})
    return d


def _score(d, device_gains):
    rf, res = d / f"rf_{device_gains}.h5", d / f"res_{device_gains}.json"
    r = CliRunner().invoke(app, ["--set", "rf_fit.physical.iterations=60", "--set", "rf_fit.physical.start_iterations=15",
                                 "--set", f"rf_fit.room.device_gains={device_gains}",
                                 "rf-fit", str(d / "scene.h5"), str(d / "meas.h5"), "-o", str(rf)])
    assert r.exit_code == 0, r.output
    r2 = CliRunner().invoke(app, ["predict", "rssi", str(rf), "--measurements", str(d / "meas.h5"),
                                  "-o", str(d / f"p_{device_gains}.h5"), "--results", str(res)])
    assert r2.exit_code == 0, r2.output
    return json.loads(res.read_text())["metrics"]["mae_db"], r.output, read_artifact(rf, "rf").free.get("model", {})


def test_a_walk_survey_scores_on_unseen_positions_as_the_better_of_gains_on_and_off(walk_survey):
    """The trap: one receiver carried to 60 positions and no ids: a gain per position (device_gains = both) fits
    every training position and carries to none. auto must choose gains that do at least as well on the held-out
    positions as the better of 'off' and 'both' (within 0.2 dB), and never a gain per receiver position."""
    auto, out, model = _score(walk_survey, "auto")
    off, _, _ = _score(walk_survey, "off")
    both, out_both, _ = _score(walk_survey, "both")
    assert "device gains: " in out and "validated on" in out
    assert "device_rx_gain_db" not in model, "a gain per receiver position was fitted"
    assert auto <= min(off, both) + 0.2, (auto, off, both)
    assert "warning: 52 device gains for 192 training links" in out_both


def test_centring_moves_the_gains_common_level_into_the_system_gain_and_keeps_every_link():
    tx, rx, ti, ri = walk(num_rx=6)
    dev = DeviceGains("both", tx, rx, 3.0, tx_id=ti)
    dev.gains["tx"].data[:] = dev.gains["tx"].data.new_tensor([-5.0, -3.0, -4.0, -6.0])
    dev.gains["rx"].data[:] = 1.0 + dev.gains["rx"].data.new_tensor(np.arange(6.0))
    before = dev.link_db().detach().numpy().copy()
    moved = dev.centre()
    assert moved == pytest.approx(-4.5 + 3.5)
    np.testing.assert_allclose(dev.link_db().detach().numpy() + moved, before)
    assert abs(float(dev.gains["tx"].mean())) < 1e-12 and abs(float(dev.gains["rx"].mean())) < 1e-12
