"""`--split holdout-rx:N` and `block-tx:SIZE`: the receiver and transmitter variants of the RSSI protocols
(a survey of fixed anchors as receivers and one beacon carried about as transmitter)."""
from __future__ import annotations

import numpy as np
import pytest

from rfir_core.errors import ConfigError
from rfir_stages.importers.split import assign_split, parse_split


def _survey(n_tx: int = 20, rx_ids=(10, 11, 20, 21, 30, 31)) -> dict:
    """Every transmitter (a grid over 10 x 8 m) to every receiver (on the walls), with rx_id and tx_id."""
    rng = np.random.default_rng(1)
    tx = np.column_stack([rng.uniform(0, 10, n_tx), rng.uniform(0, 8, n_tx), np.full(n_tx, 1.5)])
    rx = np.column_stack([np.linspace(0.2, 9.8, len(rx_ids)), np.zeros(len(rx_ids)) + 0.1, np.full(len(rx_ids), 2.3)])
    t, r = np.meshgrid(np.arange(n_tx), np.arange(len(rx_ids)), indexing="ij")
    return {"tx_pos": tx[t.ravel()], "rx_pos": rx[r.ravel()], "tx_id": t.ravel(),
            "rx_id": np.asarray(rx_ids)[r.ravel()]}


@pytest.mark.parametrize("seed", [0, 3])
def test_holdout_rx_holds_out_every_link_of_whole_receivers(seed):
    data = _survey()
    split, line = assign_split(data, parse_split("holdout-rx:2"), seed, "rssi")
    held = set(data["rx_id"][split == 1].tolist())
    assert len(held) == 2 and not held & set(data["rx_id"][split == 0].tolist())
    assert "2 of 6 receivers held out (rx_id " + ", ".join(str(v) for v in sorted(held)) + ")" in line
    again, _ = assign_split(data, parse_split("holdout-rx:2"), seed, "rssi")
    np.testing.assert_array_equal(split, again)


def test_holdout_rx_needs_a_receiver_to_train_on():
    with pytest.raises(ConfigError, match="6 receivers; holding out 6"):
        assign_split(_survey(), parse_split("holdout-rx:6"), 0, "rssi")


def test_block_tx_holds_out_whole_transmitter_squares():
    data = _survey()
    split, line = assign_split(data, parse_split("block-tx:4"), 0, "rssi")
    cell = [tuple(c) for c in np.floor(data["tx_pos"][:, :2] / 4).astype(int)]
    for c in set(cell):
        assert len({s for s, k in zip(split, cell) if k == c}) == 1       # a square is wholly train or test
    assert split.sum() >= 0.2 * split.size and split.sum() < split.size
    assert "transmitter squares of 4 m held out" in line
    # the receivers all lie in a row: block (receiver squares) holds out receivers, not an area of positions
    rx_split, _ = assign_split(data, parse_split("block:4"), 0, "rssi")
    assert set(data["rx_id"][rx_split == 1].tolist()).isdisjoint(data["rx_id"][rx_split == 0].tolist())


@pytest.mark.parametrize("text", ["holdout-rx:0", "holdout-rx:1.5", "block-tx:0", "block-tx:2:1.5"])
def test_bad_device_protocols_are_refused(text):
    with pytest.raises(ConfigError, match="--split"):
        parse_split(text)


def test_device_protocols_are_for_the_rssi_task():
    with pytest.raises(ConfigError, match="rssi task"):
        assign_split(_survey(), parse_split("holdout-rx:1"), 0, "rcs")
