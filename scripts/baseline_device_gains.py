"""The fitted log-distance and multi-wall baselines with a gain per device, scored on a split.

    python scripts/baseline_device_gains.py RF.h5 MEASUREMENTS.h5 [--prior-db 3] [--truth ML/truth.json] \
        [--results NAME.json]

`rfir predict rssi` fits its baselines without device terms; an rfir model fitted with
`rf_fit.room.device_gains = both` has them. To compare like with like, this fits the same baselines
(rfir_stages.predict.rssi_baselines: log-distance, and multi-wall with the crossings counted on RF's
Gaussians) with one gain per transmitter and per receiver added, under the room model's prior: ridge
least squares with weight s / prior_db on the gains (s the RMS training residual, iterated), which is
the MAP estimate for Gaussian dB errors. A device no training link sees gets 0 dB.
With --truth (the truth.json of `python scripts/measured_like.py`): the figures the
simulator itself scores, plus one fitted constant, without and with the true device gains (the floor
that fading and antenna patterns leave). A baseline, not a stage: it writes only its JSON.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def fit_with_devices(base: np.ndarray, tx_id: np.ndarray, rx_id: np.ndarray, y: np.ndarray, train: np.ndarray,
                     prior_db: float, rounds: int = 4) -> np.ndarray:
    """Predictions [L] dB of base [L, P] regressors + a gain per device, fitted on the rows `train` (bool)."""
    import scipy.sparse as sp
    from scipy.sparse.linalg import lsqr

    n, nt, nr = len(y), int(tx_id.max()) + 1, int(rx_id.max()) + 1
    rows = np.arange(n)
    dev = sp.hstack([sp.csr_matrix((np.ones(n), (rows, tx_id)), shape=(n, nt)),
                     sp.csr_matrix((np.ones(n), (rows, rx_id)), shape=(n, nr))])
    x = sp.hstack([sp.csr_matrix(base), dev]).tocsr()
    seen = np.zeros(nt + nr, dtype=bool)
    seen[np.unique(tx_id[train])] = True
    seen[nt + np.unique(rx_id[train])] = True
    s = float(np.std(y[train]))
    for _ in range(rounds):
        reg = sp.hstack([sp.csr_matrix((nt + nr, base.shape[1])), sp.identity(nt + nr) * (s / prior_db)])
        coef = lsqr(sp.vstack([x[train], reg]).tocsr(), np.concatenate([y[train], np.zeros(nt + nr)]),
                    atol=1e-10, btol=1e-10, iter_lim=20000)[0]
        coef[base.shape[1]:][~seen] = 0.0
        s = float(np.sqrt(np.mean((x[train] @ coef - y[train]) ** 2)))
    return x @ coef


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("rf", help="an rf artifact of the RSSI data (its Gaussians give the crossings)")
    ap.add_argument("measurements")
    ap.add_argument("--prior-db", type=float, default=3.0, help="standard deviation of the gains' prior, dB")
    ap.add_argument("--truth", default=None, help="truth.json of the measured-like transform")
    ap.add_argument("--results", default=None)
    a = ap.parse_args(argv)

    from rfir_core.artifacts import read_artifact
    from rfir_stages.model.crossings import crossing_counts
    from rfir_stages.model.radio_model import load_model

    meas = read_artifact(a.measurements, "measurements")
    rf = read_artifact(a.rf, "rf")
    tx, rx = np.asarray(meas["tx_pos"], np.float64), np.asarray(meas["rx_pos"], np.float64)
    y = np.asarray(meas["path_gain_db"], np.float64)[:, 0]
    train, test = np.asarray(meas["split"]) == 0, np.asarray(meas["split"]) == 1
    tx_id, rx_id = np.asarray(meas["tx_id"]), np.asarray(meas["rx_id"])
    d = np.linalg.norm(rx - tx, axis=1)
    names = rf.attrs.get("label_names")
    counts, _ = crossing_counts(load_model(rf, quantity="rssi").provider, rf.get("gaussians/labels"),
                                   None if names is None else list(names), tx, rx)
    ld = np.stack([np.ones_like(d), -10 * np.log10(d)], 1)
    mw = np.concatenate([ld, -counts[:, counts[train].sum(0) > 0]], 1)
    out = {}
    for name, base in (("log_distance", ld), ("multiwall", mw)):
        r = fit_with_devices(base, tx_id, rx_id, y, train, a.prior_db) - y
        out[f"{name}_device_gains_mae_db"] = float(np.abs(r[test]).mean())
        out[f"{name}_device_gains_mae_train_db"] = float(np.abs(r[train]).mean())
    if a.truth:
        truth = json.loads(Path(a.truth).read_text())
        sim = np.asarray(truth["links"]["simulated_db"])
        if len(sim) != len(y):
            raise SystemExit(f"{a.truth}: {len(sim)} links, the measurements have {len(y)}")
        gains = np.asarray(truth["tx"]["gain_db"])[tx_id] + np.asarray(truth["rx"]["gain_db"])[rx_id]
        for name, ref in (("simulator", sim), ("simulator_true_gains", sim + gains)):
            r = ref + np.median(y[train] - ref[train]) - y
            out[f"{name}_mae_db"] = float(np.abs(r[test]).mean())
            out[f"{name}_mae_train_db"] = float(np.abs(r[train]).mean())
    for k, v in out.items():
        print(f"{k}: {v:.2f} dB")
    if a.results:
        Path(a.results).parent.mkdir(parents=True, exist_ok=True)
        Path(a.results).write_text(json.dumps({"measurements": Path(a.measurements).name, "rf": Path(a.rf).name,
                                               "prior_db": a.prior_db, "num_test": int(test.sum()),
                                               "num_train": int(train.sum()), "metrics": out}, indent=1))


if __name__ == "__main__":
    main()
