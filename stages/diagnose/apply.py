"""Effects named by `rfir diagnose` and recorded in an rf artifact (free group `effects`), applied by
`rfir predict` to its predicted path gain, so the corrected model predicts new links too."""
from __future__ import annotations

import json

import numpy as np

from .crossings import crossings_from_artifact
from .rows import Rows
from .select import chain_from_json, compose


def recorded_chain(rf) -> list:
    """The [(Effect, x)] chain recorded in the rf artifact (empty when none)."""
    attrs = rf.free.get("effects@attrs", {})
    text = attrs.get("chain_json")
    return chain_from_json(json.loads(str(text))) if text else []


def apply_recorded_effects(rf, pg_db: np.ndarray, tx_m: np.ndarray, rx_m: np.ndarray, freqs_hz: np.ndarray, *,
                           aspect_rad=None, range_m=None) -> np.ndarray:
    """pg_db [L, F] with the recorded chain applied (unchanged when there is none)."""
    chain = recorded_chain(rf)
    if not chain:
        return pg_db
    n_l, n_f = pg_db.shape
    rep = lambda a: None if a is None else np.repeat(np.asarray(a, np.float64), n_f, axis=0)  # noqa: E731
    crossings = None
    if any(e.name in ("edge_diffraction", "wall_transmission", "crossing_loss") for e, _ in chain):
        crossings = rep(crossings_from_artifact(rf, tx_m, rx_m))
    flat = pg_db.reshape(-1).astype(np.float64)
    every = np.ones(flat.size, bool)
    rows = Rows(flat, flat.copy(), every, every, rep(tx_m), rep(rx_m), np.tile(np.asarray(freqs_hz, np.float64), n_l),
                str(rf.attrs.get("task", "")), rep(aspect_rad), rep(range_m), crossings)
    return compose(chain, rows).reshape(n_l, n_f)
