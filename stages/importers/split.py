"""Train/test protocols for an imported file (`rfir import csv --split ...`), written as the `split`
column (0 train, 1 test). Deterministic for a given seed (the global `--seed`).

- random:SHARE   a random SHARE (0 < SHARE < 1) of the links to test (any task).
- holdout-tx:N   every link of N randomly chosen transmitters to test (rssi task): does the model
                 predict a transmitter it never saw? Transmitters are told apart by tx_id when the
                 file has it, else by position.
- holdout-rx:N   every link of N randomly chosen receivers to test (rssi task; told apart by rx_id, else
                 by position): a survey of fixed anchors and one moving beacon (the beacon as transmitter)
                 asks whether the model predicts an anchor it never saw.
- block:SIZE[:SHARE]  receivers binned into SIZE x SIZE metre squares (x, y; the grid starts at the
                 origin); whole squares go to test, in random order, until at least SHARE (default 0.2)
                 of the links are test (rssi task): does the model predict an unseen part of the room?
- block-tx:SIZE[:SHARE]  the same with the transmitters binned: where the moving device is the
                 transmitter (a beacon carried about, fixed receivers), block on its positions.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rfir_core.errors import ConfigError

PROTOCOLS = ("random", "holdout-tx", "holdout-rx", "block", "block-tx")
RSSI_ONLY = ("holdout-tx", "holdout-rx", "block", "block-tx")
BLOCK_SHARE = 0.2
HELP = ("random:SHARE (any task; e.g. random:0.2), holdout-tx:N (rssi task; N transmitters held out), holdout-rx:N "
        "(N receivers), block:SIZE[:SHARE] (rssi task; receiver squares of SIZE metres held out, SHARE of the links, "
        "default 0.2) or block-tx:SIZE[:SHARE] (transmitter squares)")


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
    """'random:0.2', 'holdout-tx:2', 'holdout-rx:2', 'block:1.5', 'block:1.5:0.3' or 'block-tx:6' -> SplitProtocol
    (ConfigError otherwise)."""
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
    if kind in ("holdout-tx", "holdout-rx") and len(nums) == 1 and nums[0] >= 1 and nums[0] == int(nums[0]):
        return SplitProtocol(kind, nums[0], text=text)
    if kind in ("block", "block-tx") and len(nums) in (1, 2) and nums[0] > 0 and (len(nums) == 1 or 0.0 < nums[1] < 1.0):
        return SplitProtocol(kind, nums[0], nums[1] if len(nums) == 2 else BLOCK_SHARE, text=text)
    raise _bad(text)


def _devices(data: dict, side: str = "tx") -> tuple[np.ndarray, np.ndarray]:
    """([L] int: which transmitter (side "tx") or receiver ("rx") each link has, by its id column, else by
    the distinct positions; [D] the ids (or the device indices) of those devices)."""
    key = f"{side}_id"
    if key in data:
        ids, inv = np.unique(np.asarray(data[key]), return_inverse=True)
        return inv.ravel(), ids
    inv = np.unique(np.round(np.asarray(data[f"{side}_pos"], float), 6), axis=0, return_inverse=True)[1].ravel()
    return inv, np.arange(int(inv.max()) + 1 if inv.size else 0)



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
    elif protocol.kind in ("holdout-tx", "holdout-rx"):
        side = protocol.kind[-2:]
        noun = "transmitter" if side == "tx" else "receiver"
        dev, ids = _devices(data, side)
        n_dev, held = int(dev.max()) + 1, int(protocol.value)
        if held >= n_dev:
            raise ConfigError(f"--split {protocol.text!r}: the file has {n_dev} {noun}{'s' * (n_dev != 1)}; "
                              f"holding out {held} leaves none to train on")
        chosen = rng.permutation(n_dev)[:held]
        split[np.isin(dev, chosen)] = 1
        what = f"{held} of {n_dev} {noun}s held out"
        if f"{side}_id" in data:
            what += f" ({side}_id " + ", ".join(str(v) for v in sorted(ids[chosen].tolist())) + ")"
    else:
        size = protocol.value
        side = "tx" if protocol.kind == "block-tx" else "rx"
        cells = np.floor(np.asarray(data[f"{side}_pos"], float)[:, :2] / size).astype(np.int64)
        _, block = np.unique(cells, axis=0, return_inverse=True)
        block = block.ravel()
        counts = np.bincount(block)
        if counts.size < 2:
            raise ConfigError(f"--split {protocol.text!r}: every {'transmitter' if side == 'tx' else 'receiver'} "
                              f"falls in one {size:g} m square: "
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
        what = (f"{len(chosen)} of {counts.size} {'transmitter' if side == 'tx' else 'receiver'} squares of {size:g} m "
                "held out")
    n_test = int(split.sum())
    return split, (f"split {protocol.text} (seed {seed}): {what}; {n - n_test} links train, {n_test} test")
