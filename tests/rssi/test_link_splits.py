"""The split protocols for links between placed antennas (rfir_stages.model.split_protocols): random:F,
holdout_box:X0:X1:Y0:Y1 and holdout_rx:N, beside the existing ones."""
import numpy as np
import pytest

from rfir_core.errors import ConfigError, StageError
from rfir_stages.model.split_protocols import describe, protocol_masks, split_rows


def _links(n_tx=50, n_rx=6, seed=3):
    """n_tx transmitter positions over a 9 x 7 m floor x n_rx receivers, Tx-major rows."""
    rng = np.random.default_rng(seed)
    tx = np.stack([rng.uniform(0, 9, n_tx), rng.uniform(0, 7, n_tx), np.ones(n_tx)], 1)
    rx = np.stack([rng.uniform(0, 9, n_rx), rng.uniform(0, 7, n_rx), np.full(n_rx, 2.2)], 1)
    tid, rid = np.repeat(np.arange(n_tx), n_rx), np.tile(np.arange(n_rx), n_tx)
    return {"tx_pos": tx[tid], "rx_pos": rx[rid], "tx_id": tid, "rx_id": rid}


def test_random_share_is_seeded_and_of_the_asked_size():
    meas = _links()
    train, test = protocol_masks(meas, "random:0.2", "m.h5", seed=1)
    assert test.sum() == 60 and not np.any(train & test) and np.all(train | test)
    again = protocol_masks(meas, "random:0.2", "m.h5", seed=1)[1]
    other = protocol_masks(meas, "random:0.2", "m.h5", seed=2)[1]
    assert np.array_equal(test, again) and not np.array_equal(test, other)


def test_box_holds_out_every_transmitter_inside_and_nothing_else():
    meas = _links()
    train_rows, test_rows = split_rows(meas, "holdout_box:5:9:0:3.8", "m.h5")
    tx = meas["tx_pos"]
    inside = (tx[:, 0] >= 5) & (tx[:, 0] < 9) & (tx[:, 1] >= 0) & (tx[:, 1] < 3.8)
    assert inside.any() and (~inside).any()
    assert np.array_equal(test_rows, np.flatnonzero(inside)) and np.array_equal(train_rows, np.flatnonzero(~inside))
    # a held-out transmitter has no training link at all (every receiver of it tests)
    assert not np.intersect1d(meas["tx_id"][test_rows], meas["tx_id"][train_rows]).size


def test_receivers_are_held_out_whole():
    meas = _links()
    train, test = protocol_masks(meas, "holdout_rx:2", "m.h5", seed=0)
    held = np.unique(meas["rx_id"][test])
    assert len(held) == 2 and test.sum() == 2 * 50
    assert not np.isin(meas["rx_id"][train], held).any()
    # without rx_id, receivers are told apart by position: again two whole receivers
    no_id = {k: v for k, v in meas.items() if k != "rx_id"}
    test2 = protocol_masks(no_id, "holdout_rx:2", "m.h5", seed=0)[1]
    held2 = np.unique(meas["rx_id"][test2])
    assert len(held2) == 2 and np.array_equal(test2, np.isin(meas["rx_id"], held2))
    with pytest.raises(StageError, match="receivers"):
        protocol_masks(meas, "holdout_rx:6", "m.h5")


@pytest.mark.parametrize("bad", ["random:0", "random:1.5", "random:x", "holdout_box:5:9:0", "holdout_box:9:5:0:3",
                                 "holdout_rx:x"])
def test_malformed_link_protocols_are_config_errors(bad):
    with pytest.raises(ConfigError, match="split"):
        split_rows(_links(), bad, "m.h5")


def test_descriptions_name_what_is_held_out():
    assert "20%" in describe("random:0.2")
    assert "x [5, 9)" in describe("holdout_box:5:9:0:3.8")
    assert "2 receivers" in describe("holdout_rx:2")
    assert "range 3" in describe("range:3")          # the existing protocols keep their lines
