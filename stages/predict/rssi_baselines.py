"""Simple RSSI baselines fitted on the same training rows as the model.

- log-distance: PG [dB] = A - 10 n log10(d / 1 m), (A, n) by least squares.
- multi-wall: log-distance plus one loss per crossing class, PG = A - 10 n log10 d - sum_c L_c N_c,
  where N_c counts the objects of class c that the Tx-Rx segment crosses. Crossings come from the
  scene's Gaussians (the same geometry rfir uses): the segment's hits are grouped by object label,
  and an object counts as crossed when the responses of its hits add up to >= `min_response`
  (surfels tiled by rfir_stages.geom add up to ~2 on their surface and ~1 at its edge); classes
  are the label names without their trailing number (desk_03 -> desk). Without labels every hit
  surfel with response >= min_response counts once in one class "surface".
- nearest links (data only, no geometry): the mean, in dB, of the k training links nearest in the
  6-D space of (Tx, Rx) positions; on a random split these are mostly the same transmitter's
  neighbouring receivers, on held-out transmitters the nearest transmitters' same receivers.
"""
from __future__ import annotations

import re

import numpy as np
import torch


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


def class_names(label_names) -> list[str]:
    """Crossing class per label: the name without a trailing _NN (desk_03 -> desk)."""
    return [re.sub(r"_\d+$", "", str(n)) for n in label_names]


def crossing_counts(provider, labels: np.ndarray | None, label_names, tx_m: np.ndarray, rx_m: np.ndarray,
                    min_response: float = 1.0, margin_m: float = 0.02) -> tuple[np.ndarray, list[str]]:
    """[M, C] number of distinct objects of each class crossed by each segment, and the class names."""
    tx = torch.as_tensor(tx_m, dtype=torch.float64)
    diff = torch.as_tensor(rx_m, dtype=torch.float64) - tx
    length = diff.norm(dim=-1).clamp(min=1e-12)
    hits = provider.ray_hits(tx.contiguous(), (diff / length[:, None]).contiguous())
    keep = (hits.t_m > margin_m) & (hits.t_m < length[hits.query] - margin_m)
    q, g, resp = hits.query[keep].numpy(), hits.gaussian[keep].numpy(), hits.response[keep].numpy()
    if labels is None or label_names is None or len(label_names) == 0:
        counts = np.bincount(q[resp >= min_response], minlength=len(tx_m)).astype(float)[:, None]
        return counts, ["surface"]
    lab = np.asarray(labels)[g]
    ok = lab >= 0
    q, lab, resp = q[ok], lab[ok], resp[ok]
    names = class_names(label_names)
    classes = sorted(set(names))
    cls_of_label = np.array([classes.index(n) for n in names])
    total = np.zeros((len(tx_m), len(names)))
    np.add.at(total, (q, lab), resp)                           # summed response per (link, object)
    crossed = total >= min_response
    counts = np.zeros((len(tx_m), len(classes)))
    for c in range(len(classes)):
        counts[:, c] = crossed[:, cls_of_label == c].sum(1)
    return counts, classes


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
