"""Train/test protocols for an imported file (`rfir import csv --split ...`), written as the `split`
column (0 train, 1 test). Deterministic for a given seed (the global `--seed`).

- random:SHARE   a random SHARE (0 < SHARE < 1) of the links to test (any task).
- holdout-tx:N   every link of N randomly chosen transmitters to test (rssi task): does the model
                 predict a transmitter it never saw? Transmitters are told apart by tx_id when the
                 file has it, else by position.
- block:SIZE[:SHARE]  receivers binned into SIZE x SIZE metre squares (x, y; the grid starts at the
                 origin); whole squares go to test, in random order, until at least SHARE (default 0.2)
                 of the links are test (rssi task): does the model predict an unseen part of the room?
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rfir_cli.errors import ConfigError

PROTOCOLS = ("random", "holdout-tx", "block")
RSSI_ONLY = ("holdout-tx", "block")
BLOCK_SHARE = 0.2
HELP = ("random:SHARE (any task; e.g. random:0.2), holdout-tx:N (rssi task; N transmitters held out) or "
        "block:SIZE[:SHARE] (rssi task; receiver squares of SIZE metres held out, SHARE of the links, default 0.2)")


@dataclass(frozen=True)
class SplitProtocol:
    """kind: one of PROTOCOLS; value: the share (random), N (holdout-tx) or the block size [m];
    share: the test share a block split aims for."""

    kind: str
    value: float
    share: float = BLOCK_SHARE
    text: str = ""


def _bad(text: str) -> ConfigError:
    return ConfigError(f"--split {text!r}: expected {HELP}")


def parse_split(text: str) -> SplitProtocol:
    """'random:0.2', 'holdout-tx:2', 'block:1.5' or 'block:1.5:0.3' -> SplitProtocol (ConfigError otherwise)."""
    kind, _, rest = str(text).strip().partition(":")
    kind = kind.strip().lower()
    parts = rest.split(":") if rest else []
    try:
        nums = [float(p) for p in parts]
    except ValueError:
        raise _bad(text) from None
    if kind not in PROTOCOLS or not nums or not all(math.isfinite(n) for n in nums):
        raise _bad(text)
    if kind == "random" and len(nums) == 1 and 0.0 < nums[0] < 1.0:
        return SplitProtocol(kind, nums[0], text=text)
    if kind == "holdout-tx" and len(nums) == 1 and nums[0] >= 1 and nums[0] == int(nums[0]):
        return SplitProtocol(kind, nums[0], text=text)
    if kind == "block" and len(nums) in (1, 2) and nums[0] > 0 and (len(nums) == 1 or 0.0 < nums[1] < 1.0):
        return SplitProtocol(kind, nums[0], nums[1] if len(nums) == 2 else BLOCK_SHARE, text=text)
    raise _bad(text)


def _transmitters(data: dict) -> np.ndarray:
    """[L] int: which transmitter each link has (tx_id, else the distinct positions)."""
    if "tx_id" in data:
        return np.unique(np.asarray(data["tx_id"]), return_inverse=True)[1]
    return np.unique(np.round(np.asarray(data["tx_pos"], float), 6), axis=0, return_inverse=True)[1].ravel()


def assign_split(data: dict, protocol: SplitProtocol, seed: int, task: str) -> tuple[np.ndarray, str]:
    """(split [L] int64, 0 train / 1 test; one line for the import report). data: the measurements
    datasets (tx_pos, rx_pos [L, 3] m, optional tx_id). Raises ConfigError when the protocol does not
    fit the task or the links (one line naming --split)."""
    if protocol.kind in RSSI_ONLY and task != "rssi":
        raise ConfigError(f"--split {protocol.text!r}: {protocol.kind} is for the rssi task (links between placed "
                          f"antennas), this file's task is {task}: use random:SHARE")
    n = len(np.asarray(data["tx_pos"]))
    if n < 2:
        raise ConfigError(f"--split {protocol.text!r}: the file has {n} link; a split needs at least 2")
    rng = np.random.default_rng(seed)
    split = np.zeros(n, np.int64)
    if protocol.kind == "random":
        n_test = min(max(1, int(round(protocol.value * n))), n - 1)
        split[rng.permutation(n)[:n_test]] = 1
        what = f"{protocol.value:g} of the links at random"
    elif protocol.kind == "holdout-tx":
        tx = _transmitters(data)
        n_tx, held = int(tx.max()) + 1, int(protocol.value)
        if held >= n_tx:
            raise ConfigError(f"--split {protocol.text!r}: the file has {n_tx} transmitter{'s' * (n_tx != 1)}; "
                              f"holding out {held} leaves none to train on")
        chosen = rng.permutation(n_tx)[:held]
        split[np.isin(tx, chosen)] = 1
        what = f"{held} of {n_tx} transmitters held out"
    else:
        size = protocol.value
        cells = np.floor(np.asarray(data["rx_pos"], float)[:, :2] / size).astype(np.int64)
        _, block = np.unique(cells, axis=0, return_inverse=True)
        block = block.ravel()
        counts = np.bincount(block)
        if counts.size < 2:
            raise ConfigError(f"--split {protocol.text!r}: every receiver falls in one {size:g} m square: "
                              "pick a smaller SIZE")
        target, n_test, chosen = protocol.share * n, 0, []
        for b in rng.permutation(counts.size):
            if n_test + counts[b] >= n:
                continue                       # keep training links
            chosen.append(b)
            n_test += counts[b]
            if n_test >= target:
                break
        split[np.isin(block, chosen)] = 1
        what = f"{len(chosen)} of {counts.size} receiver squares of {size:g} m held out"
    n_test = int(split.sum())
    return split, (f"split {protocol.text} (seed {seed}): {what}; {n - n_test} links train, {n_test} test")
