"""NeRF2-style baseline for RSSI or monostatic RCS prediction on an rfir `measurements` artifact.

    python scripts/baseline_nerf2.py MEASUREMENTS.h5 --split random|holdout_tx --results results/NAME.json
        [--epochs N] [--minutes M] [--n-dirs 64] [--n-samples 24] [--width 64] [--batch 128] [--lr 2e-3]
    python scripts/baseline_nerf2.py MEASUREMENTS.h5 --task rcs --protocol data|every-10|sector:45:135|range:3
        --results results/NAME.json [same options]

--task: rssi or rcs (default: the artifact's task). RSSI, --split random: the artifact's split
column (1 = test, 0 = train); holdout_tx: transmitters 6, 11, 14, 17 (tx_id) are the test set, every
link of the others trains. RCS, --protocol: rfir's train/test protocols (rfir_stages.model.split_protocols);
the Tx input is the radar position (tx_pos == rx_pos), the rays leave the radar toward the object's
box (scene_bounds), and the score is on rcs_dbsm: the predicted path gain plus the file's per-row
constant rcs_dbsm - path_gain_db; nearest- and linear-aspect baselines on the same split are added.
Trains on the train rows (one frequency, path_gain_db[:, freq_index]), writes test / train MAE in
dB, times and settings to the results JSON and prints them. --minutes is a wall-clock budget for
training: the run stops cleanly after the mini-batch that crosses it and is scored as it stands.
"""
from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from rfir_core.artifacts import read_artifact
from rfir_stages.baselines.nerf2 import Nerf2Settings, predict_nerf2, train_nerf2
from rfir_stages.predict.baselines import aspect_baselines, range_baselines
from rfir_stages.model.split_protocols import describe, protocol_masks

HOLDOUT_TX = [6, 11, 14, 17]
MAX_EPOCHS_KEPT = 200   # per-epoch history entries written to the results JSON (thinned evenly, last kept)
EDIT_NOTE = "the field is learned for one scene with the source as input; moving an object needs new measurements and retraining"


def thin_history(fit: dict, keep: int = MAX_EPOCHS_KEPT) -> dict:
    """fit with its per-epoch list cut to about `keep` evenly spaced entries (the last always kept):
    a short run on few links makes thousands of epochs, which would bloat the results file."""
    ep = fit.get("epochs", [])
    if len(ep) <= keep:
        return fit
    step = -(-len(ep) // keep)
    kept = ep[::step] + ([ep[-1]] if (len(ep) - 1) % step else [])
    return {**fit, "epochs": kept, "epochs_total": len(ep), "epochs_kept_every": step}


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("measurements")
    ap.add_argument("--task", choices=["rssi", "rcs"], default=None, help="default: the artifact's task")
    ap.add_argument("--split", choices=["random", "holdout_tx"], default="random", help="rssi")
    ap.add_argument("--protocol", default="data", help="rcs: data | every-N | sector:A:B | range:R")
    ap.add_argument("--results", required=True)
    ap.add_argument("--epochs", type=int, default=Nerf2Settings.epochs)
    ap.add_argument("--minutes", type=float, default=None, help="wall-clock training budget")
    ap.add_argument("--n-dirs", type=int, default=Nerf2Settings.n_dirs)
    ap.add_argument("--n-samples", type=int, default=Nerf2Settings.n_samples)
    ap.add_argument("--width", type=int, default=Nerf2Settings.width)
    ap.add_argument("--batch", type=int, default=Nerf2Settings.batch_links)
    ap.add_argument("--lr", type=float, default=Nerf2Settings.lr)
    ap.add_argument("--n-freqs-tx", type=int, default=Nerf2Settings.n_freqs_tx)
    ap.add_argument("--n-freqs-dir", type=int, default=Nerf2Settings.n_freqs_dir)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--freq-index", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    ap.add_argument("--monitor", action="store_true", help="score the test links after every epoch (history only)")
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)

    art = read_artifact(a.measurements, "measurements")
    d = art.data
    task = a.task or str(art.attrs.get("task", "rssi"))
    if task not in ("rssi", "rcs"):
        ap.error(f"task {task!r}: expected rssi or rcs")
    tx, rx = np.asarray(d["tx_pos"], np.float64), np.asarray(d["rx_pos"], np.float64)
    y = np.asarray(d["path_gain_db"], np.float64)[:, a.freq_index]
    freq = float(d["freq_hz"][a.freq_index])
    if task == "rssi":
        split_name = a.split
        if a.split == "random":
            test = d["split"].astype(int) == 1
            split_desc = "random split of the file (split column)"
        else:
            test = np.isin(d["tx_id"], HOLDOUT_TX)
            split_desc = f"held-out transmitters {HOLDOUT_TX} (tx_id)"
        train_idx, test_idx = np.flatnonzero(~test), np.flatnonzero(test)
        score = y                                            # scored on path gain (dB)
    else:
        if "rcs_dbsm" not in d:
            ap.error("--task rcs needs rcs_dbsm in the measurements")
        split_name = a.protocol
        train_m, test_m = protocol_masks(d, a.protocol, str(a.measurements))
        split_desc = describe(a.protocol)
        train_idx, test_idx = np.flatnonzero(train_m), np.flatnonzero(test_m)
        score = np.asarray(d["rcs_dbsm"], np.float64)[:, a.freq_index]   # scored on RCS (dBsm)
    if len(train_idx) == 0 or len(test_idx) == 0:
        ap.error(f"split {split_name!r}: {len(train_idx)} train / {len(test_idx)} test rows")
    to_score = score - y                                     # per-row constant; 0 for rssi
    bounds = d.get("scene_bounds")
    if bounds is None:
        allp = np.concatenate([tx, rx])
        bounds = np.stack([allp.min(0) - 0.5, allp.max(0) + 0.5])

    s = Nerf2Settings(epochs=a.epochs, minutes=a.minutes, n_dirs=a.n_dirs, n_samples=a.n_samples,
                      width=a.width, batch_links=a.batch, lr=a.lr, seed=a.seed, n_freqs_tx=a.n_freqs_tx,
                      n_freqs_dir=a.n_freqs_dir)

    def progress(info: dict) -> None:
        extra = f"  test {info['mae_eval_db']:.3f} dB" if "mae_eval_db" in info else ""
        print(f"epoch {info['epoch']:3d}  loss {info['loss']:8.3f}  train(running) {info['mae_train_db']:.3f} dB"
              f"{extra}  lr {info['lr']:.2e}  {info['elapsed_s']:7.1f} s{'  (budget hit)' if info['partial'] else ''}",
              flush=True)

    print(f"{task} {split_name}: {len(train_idx)} train / {len(test_idx)} test links, {freq / 1e9:g} GHz",
          flush=True)
    t0 = time.perf_counter()
    field, hist = train_nerf2(tx, rx, y, train_idx, s, progress=progress, bounds=bounds,
                              eval_idx=test_idx if a.monitor else None)
    train_s = time.perf_counter() - t0
    t1 = time.perf_counter()
    pred = predict_nerf2(field, tx, rx, s.eval_batch) + to_score
    predict_s = time.perf_counter() - t1
    wall = time.perf_counter() - t0
    y = score
    mae_test = float(np.mean(np.abs(pred[test_idx] - y[test_idx])))
    mae_train = float(np.mean(np.abs(pred[train_idx] - y[train_idx])))
    mean_mae = float(np.mean(np.abs(y[train_idx].mean() - y[test_idx])))
    out = {
        "name": Path(a.results).stem,
        "task": task,
        "scene": str(art.attrs.get("scene", "")),
        "method": "nerf2 (NeRF2-style neural radio field, our implementation; rfir_stages.baselines.nerf2)",
        "measurements": str(a.measurements),
        "freq_hz": freq,
        "split": split_name,
        "seed": a.seed,
        "metrics": {
            "split": split_desc,
            "num_train": int(len(train_idx)),
            "num_test": int(len(test_idx)),
            "mae_db": mae_test,
            "mae_train_db": mae_train,
            "rmse_db": float(np.sqrt(np.mean((pred[test_idx] - y[test_idx]) ** 2))),
            "baseline_train_mean_mae_db": mean_mae,
        },
        "settings": asdict(s),
        "num_parameters": int(sum(p.numel() for p in field.parameters())),
        "fit": thin_history({k: v for k, v in hist.items() if k != "settings"}),
        "train_time_s": train_s,
        "predict_time_s": predict_s,
        "wall_time_s": wall,
        "threads": a.threads,
        "supports_edit": False,
        "edit_note": EDIT_NOTE,
    }
    if task == "rcs":
        out["split_protocol"] = a.protocol
        asp, rng = np.asarray(d["aspect_rad"], np.float64), np.asarray(d["range_m"], np.float64)
        base = {**aspect_baselines(asp, rng, score[:, None], train_idx, test_idx),
                **range_baselines(asp, rng, score[:, None], train_idx, test_idx)}
        for k, b in base.items():   # a baseline that has no training rows to copy (e.g. aspect ones at an unseen range) is left out
            err = np.abs(b[:, 0] - y[test_idx])
            if np.isfinite(err).all():
                out["metrics"][f"baseline_{k}_mae_db"] = float(err.mean())

    Path(a.results).parent.mkdir(parents=True, exist_ok=True)
    Path(a.results).write_text(json.dumps(out, indent=2) + "\n")
    extra = "".join(f"  {k[len('baseline_'):-len('_mae_db')]} {v:.3f} dB" for k, v in out["metrics"].items()
                    if k.startswith("baseline_") and k != "baseline_train_mean_mae_db")
    print(f"test MAE {mae_test:.3f} dB  train MAE {mae_train:.3f} dB  (train-mean predictor {mean_mae:.3f} dB){extra}  "
          f"epochs {len(hist['epochs'])} ({hist['stopped_by']})  train {train_s:.0f} s  wall {wall:.0f} s  -> {a.results}")
    return out


if __name__ == "__main__":
    main()
