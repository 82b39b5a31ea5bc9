"""Simple RSSI baselines fitted on the same training rows as the model.

- log-distance: PG [dB] = A - 10 n log10(d / 1 m), (A, n) by least squares.
- multi-wall: log-distance plus one loss per crossing class, PG = A - 10 n log10 d - sum_c L_c N_c,
  where N_c counts the objects of class c that the Tx-Rx segment crosses, from the scene's Gaussians (the same
  geometry rfir uses; rfir_stages.model.crossings.crossing_counts says what counts as crossed).
- nearest links (data only, no geometry): the mean, in dB, of the k training links nearest in the
  6-D space of (Tx, Rx) positions; on a random split these are mostly the same transmitter's
  neighbouring receivers, on held-out transmitters the nearest transmitters' same receivers.
"""
from __future__ import annotations


import numpy as np


def _lstsq(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    coef, *_ = np.linalg.lstsq(x, y, rcond=None)
    return coef


def fit_log_distance(dist_m: np.ndarray, pg_db: np.ndarray) -> dict:
    """{'A_db', 'n'} fitted on distances [M] m and path gains [M] dB."""
    x = np.stack([np.ones_like(dist_m), -10 * np.log10(dist_m)], 1)
    a, n = _lstsq(x, pg_db)
    return {"A_db": float(a), "n": float(n)}


def predict_log_distance(params: dict, dist_m: np.ndarray) -> np.ndarray:
    return params["A_db"] - 10 * params["n"] * np.log10(dist_m)


def fit_multiwall(dist_m: np.ndarray, counts: np.ndarray, pg_db: np.ndarray, classes: list[str]) -> dict:
    """{'A_db', 'n', 'loss_db': {class: L_c}}; classes never crossed in training get L_c = 0."""
    used = np.flatnonzero(counts.sum(0) > 0)
    x = np.concatenate([np.ones((len(dist_m), 1)), -10 * np.log10(dist_m)[:, None], -counts[:, used]], 1)
    coef = _lstsq(x, pg_db)
    loss = {c: 0.0 for c in classes}
    for j, c in enumerate(used):
        loss[classes[c]] = float(coef[2 + j])
    return {"A_db": float(coef[0]), "n": float(coef[1]), "loss_db": loss}


def predict_multiwall(params: dict, dist_m: np.ndarray, counts: np.ndarray, classes: list[str]) -> np.ndarray:
    loss = np.array([params["loss_db"].get(c, 0.0) for c in classes])
    return params["A_db"] - 10 * params["n"] * np.log10(dist_m) - counts @ loss


def nearest_links(tx_m: np.ndarray, rx_m: np.ndarray, pg_db: np.ndarray, train: np.ndarray, test: np.ndarray,
                  k: int = 4) -> np.ndarray:
    """[T] mean path gain [dB] of the k training links nearest to each test link in (Tx, Rx) space."""
    from scipy.spatial import cKDTree

    pts = np.concatenate([tx_m, rx_m], 1)
    k = min(k, len(train))
    _, idx = cKDTree(pts[train]).query(pts[test], k=k)
    return pg_db[train][np.asarray(idx).reshape(len(test), k)].mean(1)
