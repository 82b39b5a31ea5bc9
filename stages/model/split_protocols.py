"""Train/test protocols over the rows of a measurement file (`rf_fit.split`, `--split`).

The paper trains on even aspects and tests on odd ones; at 1 degree steps that protocol rewards
interpolation (copying the nearest training aspect already scores well), so rfir also reports
harder ones. A protocol is a short string:

- "data": the file's own `split` column (0 train, 1 test; other values unused).
- "every-N": aspects on a grid of N times the measured step train (aspect index % N == 0), the
  rest test. The index counts aspects in the file's step from the smallest aspect.
- "sector:A:B": aspects in [A, B) degrees (wrapping, e.g. "sector:315:45") test, the rest train.
- "range:R": rows at range R metres test, the other ranges train.

For links between placed antennas (rssi), written into a file's `split` column by
`rfir_stages.simulate.measured_like` (rf-fit then reads them with `rf_fit.rssi.split = "file"`):

- "random:F": a share F of the rows, drawn at random with the seed, test.
- "holdout_box:X0:X1:Y0:Y1": every link whose transmitter lies in the box X0 <= x < X1,
  Y0 <= y < Y1 (metres; a room) tests: positions the fit never saw, in a room it never saw inside.
- "holdout_rx:N": every link of N receivers drawn at random with the seed tests (unseen devices).

`split_rows` returns (train_rows, test_rows) as row indices; rf-fit records the protocol and
its training rows in the rf artifact, and `predict rcs` rebuilds the test rows from the protocol.
"""
from __future__ import annotations

import numpy as np

from rfir_core.errors import ConfigError, StageError


def _aspect_deg(meas, where: str) -> np.ndarray:
    asp = meas.get("aspect_rad")
    if asp is None:
        raise StageError("this split protocol needs aspect_rad (rcs or wideband measurements)", path=where)
    return np.mod(np.degrees(np.asarray(asp, np.float64)), 360.0)


def _every(meas, n: int, where: str) -> np.ndarray:
    deg = _aspect_deg(meas, where)
    values = np.unique(np.round(deg, 6))
    step = float(np.min(np.diff(values))) if values.size > 1 else 360.0
    index = np.round((deg - values[0]) / step).astype(np.int64)
    return index % n != 0                       # test mask


def _sector(meas, a: float, b: float, where: str) -> np.ndarray:
    deg = _aspect_deg(meas, where)
    a, b = a % 360.0, b % 360.0
    return (deg >= a) & (deg < b) if a < b else (deg >= a) | (deg < b)


def _range(meas, r: float, where: str) -> np.ndarray:
    rng = meas.get("range_m")
    if rng is None:
        raise StageError("split 'range:R' needs range_m in the measurements", path=where)
    return np.abs(np.asarray(rng, np.float64) - r) < 1e-6


def _random(meas, fraction: float, seed: int) -> np.ndarray:
    if not 0.0 < fraction < 1.0:
        raise ValueError
    n = len(np.asarray(meas["tx_pos"]))
    test = np.zeros(n, dtype=bool)
    test[np.random.default_rng(seed).permutation(n)[: int(round(fraction * n))]] = True
    return test


def _box(meas, x0: float, x1: float, y0: float, y1: float) -> np.ndarray:
    if not (x0 < x1 and y0 < y1):
        raise ValueError
    tx = np.asarray(meas["tx_pos"], np.float64)
    return (tx[:, 0] >= x0) & (tx[:, 0] < x1) & (tx[:, 1] >= y0) & (tx[:, 1] < y1)


def _receivers(meas, count: int, seed: int, where: str) -> np.ndarray:
    """Links of `count` receivers drawn at random with `seed` (by rx_id, else by position)."""
    rx_id = meas.get("rx_id")
    if rx_id is None:
        _, rx_id = np.unique(np.round(np.asarray(meas["rx_pos"], np.float64), 3), axis=0, return_inverse=True)
    rx_id = np.asarray(rx_id).reshape(-1)
    ids = np.unique(rx_id)
    if not 0 < count < len(ids):
        raise StageError(f"split 'holdout_rx:{count}': need 0 < N < {len(ids)} receivers", path=where)
    held = np.random.default_rng(seed).choice(ids, size=count, replace=False)
    return np.isin(rx_id, held)


def protocol_masks(meas, protocol: str, where: str, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(train [L] bool, test [L] bool) for `protocol` over the rows of `meas`; seed: of the random ones."""
    name, _, arg = protocol.partition(":")
    try:
        if name == "data":
            split = meas.get("split")
            if split is None:
                raise StageError("the measurements have no 'split' (0 train, 1 test); add one or use --split",
                                 path=where)
            split = np.asarray(split)
            return split == 0, split == 1
        if name.startswith("every-"):
            n = int(name[len("every-"):])
            if n < 2:
                raise ValueError
            test = _every(meas, n, where)
        elif name == "sector":
            a, b = (float(x) for x in arg.split(":"))
            test = _sector(meas, a, b, where)
        elif name == "range":
            test = _range(meas, float(arg), where)
        elif name == "random":
            test = _random(meas, float(arg), seed)
        elif name == "holdout_box":
            test = _box(meas, *(float(x) for x in arg.split(":")))
        elif name == "holdout_rx":
            test = _receivers(meas, int(arg), seed, where)
        else:
            raise ValueError
    except (ValueError, TypeError):
        raise ConfigError(f"split {protocol!r}: expected data, every-N (N >= 2), sector:A:B (degrees), "
                          "range:R (metres), random:F (0 < F < 1), holdout_box:X0:X1:Y0:Y1 (metres) "
                          "or holdout_rx:N") from None
    return ~test, test


def split_rows(meas, protocol: str, where: str, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(train_rows, test_rows) row indices; a clear error when the training rows are empty (a protocol
    that holds nothing out may still be fitted: every row trains)."""
    train, test = protocol_masks(meas, protocol, where, seed)
    if not train.any():
        raise StageError(f"empty training split: protocol {protocol!r} leaves no row to fit", path=where)
    if protocol != "data" and not test.any():
        raise StageError(f"split {protocol!r} holds out no row (nothing to test)", path=where)
    return np.flatnonzero(train), np.flatnonzero(test)


def describe(protocol: str) -> str:
    """One line for results files and plots."""
    name, _, arg = protocol.partition(":")
    if name == "data":
        return "the file's split column: rows with split == 0 train, split == 1 test (paper: even aspects / odd)"
    if name.startswith("every-"):
        return f"every {name[6:]}th aspect trains, the others test"
    if name == "sector":
        a, b = arg.split(":")
        return f"aspects in [{a}, {b}) deg held out (test), the rest train"
    if name == "range":
        return f"rows at range {arg} m held out (test), the other ranges train"
    if name == "random":
        return f"a random {float(arg):.0%} of the links held out (test), the rest train"
    if name == "holdout_box":
        x0, x1, y0, y1 = arg.split(":")
        return f"links whose transmitter lies in x [{x0}, {x1}), y [{y0}, {y1}) m held out (test), the rest train"
    if name == "holdout_rx":
        return f"every link of {arg} receivers drawn at random held out (test), the rest train"
    return protocol
