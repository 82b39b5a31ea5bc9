"""NeRF2-style baseline for RSSI prediction on an rfir `measurements` artifact.

    python scripts/baseline_nerf2.py MEASUREMENTS.h5 --split random|holdout_tx --results results/NAME.json
        [--epochs N] [--minutes M] [--n-dirs 64] [--n-samples 24] [--width 64] [--batch 128] [--lr 2e-3]

random: the artifact's split column (1 = test, 0 = train); holdout_tx: transmitters 6, 11, 14, 17
(tx_id) are the test set, every link of the others trains. Trains on the train rows (one frequency,
path_gain_db[:, freq_index]), writes test / train MAE in dB, wall time and settings to the results
JSON and prints them. --minutes is a wall-clock budget for training: the run stops cleanly after the
mini-batch that crosses it and is scored as it stands.
"""
from __future__ import annotations

import argparse
import json
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from rfir_cli.artifacts import read_artifact
from rfir_stages.baselines.nerf2 import Nerf2Settings, predict_nerf2, train_nerf2

HOLDOUT_TX = [6, 11, 14, 17]


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("measurements")
    ap.add_argument("--split", choices=["random", "holdout_tx"], default="random")
    ap.add_argument("--results", required=True)
    ap.add_argument("--epochs", type=int, default=Nerf2Settings.epochs)
    ap.add_argument("--minutes", type=float, default=None, help="wall-clock training budget")
    ap.add_argument("--n-dirs", type=int, default=Nerf2Settings.n_dirs)
    ap.add_argument("--n-samples", type=int, default=Nerf2Settings.n_samples)
    ap.add_argument("--width", type=int, default=Nerf2Settings.width)
    ap.add_argument("--batch", type=int, default=Nerf2Settings.batch_links)
    ap.add_argument("--lr", type=float, default=Nerf2Settings.lr)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--freq-index", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    ap.add_argument("--monitor", action="store_true", help="score the test links after every epoch (history only)")
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)

    art = read_artifact(a.measurements, "measurements")
    d = art.data
    tx, rx = d["tx_pos"].astype(np.float64), d["rx_pos"].astype(np.float64)
    y = d["path_gain_db"][:, a.freq_index].astype(np.float64)
    freq = float(d["freq_hz"][a.freq_index])
    if a.split == "random":
        test = d["split"].astype(int) == 1
        split_desc = "random split of the file (split column)"
    else:
        test = np.isin(d["tx_id"], HOLDOUT_TX)
        split_desc = f"held-out transmitters {HOLDOUT_TX} (tx_id)"
    train_idx, test_idx = np.flatnonzero(~test), np.flatnonzero(test)
    bounds = d.get("scene_bounds")
    if bounds is None:
        allp = np.concatenate([tx, rx])
        bounds = np.stack([allp.min(0) - 0.5, allp.max(0) + 0.5])

    s = Nerf2Settings(epochs=a.epochs, minutes=a.minutes, n_dirs=a.n_dirs, n_samples=a.n_samples,
                      width=a.width, batch_links=a.batch, lr=a.lr, seed=a.seed)

    def progress(info: dict) -> None:
        extra = f"  test {info['mae_eval_db']:.3f} dB" if "mae_eval_db" in info else ""
        print(f"epoch {info['epoch']:3d}  loss {info['loss']:8.3f}  train(running) {info['mae_train_db']:.3f} dB"
              f"{extra}  lr {info['lr']:.2e}  {info['elapsed_s']:7.1f} s{'  (budget hit)' if info['partial'] else ''}",
              flush=True)

    print(f"{a.split}: {len(train_idx)} train / {len(test_idx)} test links, {freq / 1e9:g} GHz", flush=True)
    t0 = time.perf_counter()
    field, hist = train_nerf2(tx, rx, y, train_idx, s, progress=progress, bounds=bounds,
                              eval_idx=test_idx if a.monitor else None)
    train_s = time.perf_counter() - t0
    pred = predict_nerf2(field, tx, rx, s.eval_batch)
    wall = time.perf_counter() - t0
    mae_test = float(np.mean(np.abs(pred[test_idx] - y[test_idx])))
    mae_train = float(np.mean(np.abs(pred[train_idx] - y[train_idx])))
    mean_mae = float(np.mean(np.abs(y[train_idx].mean() - y[test_idx])))
    out = {
        "name": Path(a.results).stem,
        "task": "rssi",
        "scene": str(art.attrs.get("scene", "")),
        "method": "nerf2 (NeRF2-style neural radio field, our implementation; rfir_stages.baselines.nerf2)",
        "measurements": str(a.measurements),
        "freq_hz": freq,
        "split": a.split,
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
        "fit": {k: v for k, v in hist.items() if k != "settings"},
        "train_time_s": train_s,
        "wall_time_s": wall,
        "threads": a.threads,
    }
    Path(a.results).parent.mkdir(parents=True, exist_ok=True)
    Path(a.results).write_text(json.dumps(out, indent=2) + "\n")
    print(f"test MAE {mae_test:.3f} dB  train MAE {mae_train:.3f} dB  (train-mean predictor {mean_mae:.3f} dB)  "
          f"epochs {len(hist['epochs'])} ({hist['stopped_by']})  train {train_s:.0f} s  wall {wall:.0f} s  -> {a.results}")
    return out


if __name__ == "__main__":
    main()
