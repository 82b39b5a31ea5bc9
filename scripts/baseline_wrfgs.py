"""WRF-GS-style baseline (Gaussians with source-entangled signals) on an rfir `measurements` artifact.

    python scripts/baseline_wrfgs.py MEASUREMENTS.h5 --scene SCENE.h5 --task rssi --split random|holdout_tx
        --results results/NAME.json [--minutes M] [--epochs N] [--threads 1] [--quick]
    python scripts/baseline_wrfgs.py MEASUREMENTS.h5 --scene SCENE.h5 --task rcs
        --protocol data|every-10|sector:45:135|range:3 --results results/NAME.json [...]

The Gaussians (frozen geometry) come from the rfir `scene` artifact SCENE.h5 (--max-gaussians:
a random subset). rssi: --split random uses the file's split column (1 = test), holdout_tx holds out
transmitters 6, 11, 14, 17 (tx_id). rcs: the radar (tx_pos == rx_pos) is the "transmitter" input and
the rays from it are aimed at the Gaussians (a cone); --protocol picks train/test rows as rf-fit does
(rfir_stages.model.split_protocols). The model fits path_gain_db[:, freq_index]; for rcs the score is on
rcs_dbsm = predicted path gain + (rcs_dbsm - path_gain_db) of the row (a per-row constant of the file).
--val-frac (default 0.1): a random part of the TRAINING rows is held out for validation and the
epoch with the best validation MAE is kept (early stopping); the test rows are never looked at before
the final scoring. --minutes is a wall-clock training budget (the run stops after the mini-batch that
crosses it); --quick: tiny settings for smoke tests.
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
from rfir_stages.baselines.wrfgs import WrfgsSettings, predict_wrfgs, train_wrfgs
from rfir_stages.model.links import geometry_from_artifact
from rfir_stages.model.split_protocols import describe, protocol_masks

HOLDOUT_TX = [6, 11, 14, 17]
EDIT_NOTE = "the signal is learned per transmitter position; moving an object needs new measurements and retraining"


def _settings(a, task: str) -> WrfgsSettings:
    kw = dict(rays="cone" if task == "rcs" else "sphere", n_freqs_tx=6 if task == "rcs" else 4,
              batch_links=32 if task == "rcs" else 64, epochs=400 if task == "rcs" else 40)
    if a.quick:
        kw.update(n_dirs=16, width=16, feat_dim=4, epochs=2, batch_links=16)
    for k, v in (("n_dirs", a.n_dirs), ("width", a.width), ("batch_links", a.batch), ("lr", a.lr),
                 ("epochs", a.epochs), ("max_gaussians", a.max_gaussians)):
        if v is not None:
            kw[k] = v
    return WrfgsSettings(minutes=a.minutes, seed=a.seed, **kw)


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("measurements")
    ap.add_argument("--scene", required=True, help="rfir scene artifact with the Gaussians")
    ap.add_argument("--task", choices=["rssi", "rcs"], default=None, help="default: the file's task attribute")
    ap.add_argument("--split", choices=["random", "holdout_tx"], default="random", help="rssi")
    ap.add_argument("--protocol", default="data", help="rcs: data | every-N | sector:A:B | range:R")
    ap.add_argument("--results", required=True)
    ap.add_argument("--epochs", type=int, default=None)
    ap.add_argument("--minutes", type=float, default=None, help="wall-clock training budget")
    ap.add_argument("--n-dirs", type=int, default=None)
    ap.add_argument("--width", type=int, default=None)
    ap.add_argument("--batch", type=int, default=None)
    ap.add_argument("--lr", type=float, default=None)
    ap.add_argument("--max-gaussians", type=int, default=None, help="random subset of the scene's Gaussians")
    ap.add_argument("--val-frac", type=float, default=0.1,
                    help="part of the training rows held out for early stopping (0: none)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--freq-index", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    ap.add_argument("--quick", action="store_true", help="tiny settings (smoke test)")
    ap.add_argument("--monitor", action="store_true", help="score the test links after every epoch (history only)")
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)
    t_start = time.perf_counter()

    art = read_artifact(a.measurements, "measurements")
    d = art.data
    task = a.task or str(art.attrs.get("task", "rssi"))
    if task not in ("rssi", "rcs"):
        raise SystemExit(f"task {task!r}: expected rssi or rcs")
    tx, rx = d["tx_pos"].astype(np.float64), d["rx_pos"].astype(np.float64)
    y = d["path_gain_db"][:, a.freq_index].astype(np.float64)
    freq = float(d["freq_hz"][a.freq_index])
    if task == "rssi":
        split_name = a.split
        if a.split == "random":
            test = d["split"].astype(int) == 1
            train = ~test
            split_desc = "random split of the file (split column)"
        else:
            test = np.isin(d["tx_id"], HOLDOUT_TX)
            train = ~test
            split_desc = f"held-out transmitters {HOLDOUT_TX} (tx_id)"
    else:
        split_name = a.protocol
        train, test = protocol_masks(d, a.protocol, str(a.measurements))
        split_desc = describe(a.protocol)
    train_idx, test_idx = np.flatnonzero(train), np.flatnonzero(test)
    if not len(train_idx) or not len(test_idx):
        raise SystemExit(f"split {split_name!r}: {len(train_idx)} train / {len(test_idx)} test rows")

    rng = np.random.default_rng(a.seed)
    n_val = int(round(a.val_frac * len(train_idx))) if len(train_idx) >= 5 else 0
    val_idx = np.sort(rng.permutation(train_idx)[:n_val]) if n_val else np.zeros(0, dtype=np.int64)
    fit_idx = np.setdiff1d(train_idx, val_idx)
    geom = geometry_from_artifact(read_artifact(a.scene, "scene"))
    geometry = (geom.means.numpy(), geom.log_scales.numpy(), geom.rotations.numpy())
    s = _settings(a, task)

    def progress(info: dict) -> None:
        if info["epoch"] % (20 if task == "rcs" else 1) and not info["partial"]:
            return
        extra = f"  val {info['mae_val_db']:.3f} dB" if "mae_val_db" in info else ""
        extra += f"  test {info['mae_eval_db']:.3f} dB" if "mae_eval_db" in info else ""
        print(f"epoch {info['epoch']:3d}  loss {info['loss']:8.3f}  train(running) {info['mae_train_db']:.3f} dB"
              f"{extra}  lr {info['lr']:.2e}  {info['elapsed_s']:7.1f} s{'  (budget hit)' if info['partial'] else ''}",
              flush=True)

    print(f"{task} {split_name}: {len(train_idx)} train ({len(val_idx)} of them for validation) / "
          f"{len(test_idx)} test links, {freq / 1e9:g} GHz, "
          f"{len(geometry[0])} Gaussians, {s.n_dirs} rays ({s.rays})", flush=True)
    t0 = time.perf_counter()
    field, hist = train_wrfgs(geometry, tx, rx, y, fit_idx, s, progress=progress,
                              eval_idx=test_idx if a.monitor else None, val_idx=val_idx if n_val else None)
    train_s = time.perf_counter() - t0
    t1 = time.perf_counter()
    pred = predict_wrfgs(field, tx, rx, s.eval_batch)      # traces the receivers again: the full cost
    predict_s = time.perf_counter() - t1
    mae_test = float(np.mean(np.abs(pred[test_idx] - y[test_idx])))
    mae_train = float(np.mean(np.abs(pred[train_idx] - y[train_idx])))
    mean_mae = float(np.mean(np.abs(y[train_idx].mean() - y[test_idx])))
    metrics = {
        "split": split_desc,
        "num_train": int(len(train_idx)),
        "num_test": int(len(test_idx)),
        "num_val": int(len(val_idx)),
        "mae_db": mae_test,
        "mae_train_db": mae_train,
        "rmse_db": float(np.sqrt(np.mean((pred[test_idx] - y[test_idx]) ** 2))),
        "baseline_train_mean_mae_db": mean_mae,
    }
    if task == "rcs":
        rcs = d["rcs_dbsm"][:, a.freq_index].astype(np.float64)
        rcs_pred = pred + (rcs - y)           # the file's per-row constant rcs_dbsm - path_gain_db
        metrics["mae_db"] = float(np.mean(np.abs(rcs_pred[test_idx] - rcs[test_idx])))
        metrics["mae_train_db"] = float(np.mean(np.abs(rcs_pred[train_idx] - rcs[train_idx])))
        metrics["quantity"] = "rcs_dbsm (predicted path gain + the row's rcs_dbsm - path_gain_db)"
    wall = time.perf_counter() - t_start
    out = {
        "name": Path(a.results).stem,
        "task": task,
        "scene": str(art.attrs.get("scene", "")),
        "method": "wrfgs (WRF-GS-style Gaussians with source-entangled signals, our implementation; "
                  "rfir_stages.baselines.wrfgs)",
        "measurements": str(a.measurements),
        "scene_artifact": str(a.scene),
        "freq_hz": freq,
        "split": split_name,
        "seed": a.seed,
        "metrics": metrics,
        "settings": {**asdict(s), "val_frac": a.val_frac},
        "num_parameters": int(sum(p.numel() for p in field.parameters())),
        "fit": {k: v for k, v in hist.items() if k != "settings"},
        "train_time_s": train_s,
        "predict_time_s": predict_s,
        "wall_time_s": wall,
        "threads": a.threads,
        "supports_edit": False,
        "edit_note": EDIT_NOTE,
    }
    Path(a.results).parent.mkdir(parents=True, exist_ok=True)
    Path(a.results).write_text(json.dumps(out, indent=2) + "\n")
    print(f"wrfgs {task} {split_name}: test MAE {metrics['mae_db']:.3f} dB  train MAE {metrics['mae_train_db']:.3f} dB  "
          f"(train-mean predictor {mean_mae:.3f} dB)  epochs {len(hist['epochs'])} ({hist['stopped_by']}, "
          f"kept {hist.get('best_epoch', len(hist['epochs']))})  "
          f"train {train_s:.0f} s  predict {predict_s:.1f} s  wall {wall:.0f} s  -> {a.results}", flush=True)
    return out


if __name__ == "__main__":
    main()
