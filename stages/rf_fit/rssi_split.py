"""Which RSSI links train a model: the `[rf_fit.rssi]` split protocol (configs/rf_fit.toml).

`split = "file"`: the rows with split == 0 of the measurement file; `split = "holdout_tx"`: every row
except those of `holdout_tx` transmitters drawn at random with the seed. rf-fit of the room model,
`predict rssi` (which scores the held-out rows) and the calibrated Sionna baseline choose the same rows.
"""
from __future__ import annotations

import numpy as np

from rfir_core.errors import ConfigError, StageError

from rfir_stages.model.links import pick_rows

SPLITS = ("file", "holdout_tx")


def rssi_settings(config: dict) -> dict:
    """The [rf_fit.rssi] table of the [rf_fit] table `config`, over the defaults of configs/rf_fit.toml, checked."""
    from rfir_core.config import load_defaults

    cfg = dict(load_defaults().get("rf_fit", {}).get("rssi", {}))
    given = dict(config.get("rssi", {}) or {})
    unknown = sorted(set(given) - set(cfg))
    if unknown:
        raise ConfigError(f"rf_fit.rssi: unknown key(s) {', '.join(unknown)} (known: {', '.join(sorted(cfg))})")
    cfg.update(given)
    if cfg["split"] not in SPLITS:
        raise ConfigError(f"rf_fit.rssi.split = {cfg['split']!r}: expected 'file' or 'holdout_tx'")
    return cfg


def holdout_transmitters(tx_id: np.ndarray, count: int, seed: int) -> np.ndarray:
    """`count` distinct transmitter ids drawn at random with `seed` (sorted)."""
    ids = np.unique(tx_id)
    if not 0 < count < len(ids):
        raise ConfigError(f"rf_fit.rssi.holdout_tx = {count}: need 0 < holdout_tx < {len(ids)} transmitters")
    return np.sort(np.random.default_rng(seed).choice(ids, size=count, replace=False))


def training_rows(meas, cfg: dict, seed: int, where: str) -> tuple[np.ndarray, np.ndarray]:
    """(train rows, held-out transmitter ids) per the split protocol of `cfg` (rssi_settings)."""
    if cfg["split"] == "file":
        return pick_rows(meas.get("split"), 0, where), np.zeros(0, np.int64)
    tx_id = meas.get("tx_id")
    if tx_id is None:
        raise StageError("split 'holdout_tx' needs tx_id in the measurements", path=where)
    held = holdout_transmitters(np.asarray(tx_id), int(cfg["holdout_tx"]), seed)
    return np.flatnonzero(~np.isin(np.asarray(tx_id), held)), held
