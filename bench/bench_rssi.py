"""Benchmark of `predict rssi` (issue 8): a 440-point radio map for a new transmitter in the classroom.

    .venv/bin/python bench/bench_rssi.py                 # classroom surfels at 0.8 m, 22 x 20 receivers
    .venv/bin/python bench/bench_rssi.py --spacing 0.5
    .venv/bin/python bench/bench_rssi.py --rf rf.h5 --results results/classroom_rssi_speed.json   # a fitted model

Needs no simulator: the classroom's meshes are built by code (rfir_stages.simulate.scenes); a short
fit of the room model on free-space data for two transmitters gives an `rf` artifact, then the map
of a third transmitter (not fitted) is timed: trace the paths of 440 links and evaluate them.
Budget in the issue: 2 s on the 2-core CPU.
Prints the timings and writes bench/rssi.json.
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from rfir_cli.artifacts import read_artifact, write_artifact
from rfir_cli.physics.closed_forms import friis_path_gain
from rfir_stages.geom import scene_from_mesh, write_scene_artifact
from rfir_stages.predict.rssi_model_io import load_predictor
from rfir_stages.rf_fit.stage import run as rf_fit
from rfir_stages.simulate.rssi import grid_positions

FREQ = 2.4e9


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--spacing", type=float, default=0.8, help="surfel spacing [m]")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rf", type=Path, help="time this fitted RSSI model instead of a 5-step synthetic fit")
    ap.add_argument("--results", type=Path, help="also write the figures to this JSON")
    args = ap.parse_args()
    bounds = np.array([[0.0, 0.0, 0.0], [9.0, 7.0, 3.0]])
    rx = grid_positions(bounds, 22, 20, 1.0, 0.4)
    tx = np.array([[2.4, 2.7, 2.2], [6.6, 4.3, 2.2]])
    if args.rf is not None:
        rf = read_artifact(args.rf, "rf")
        out = {"rf": str(args.rf), "num_gaussians": int(len(rf["rf/opacity"])), "num_points": len(rx),
               "new_tx_m": [4.1, 3.3, 1.7], "budget_s": 2.0, **_time_map(args.rf, rx, args.repeats),
               "fit_s": float(rf.free["training@attrs"]["wall_time_s"]),
               "fit_trace_s": float(rf.free["training@attrs"]["trace_time_s"]),
               "fit_budget_s": 1800.0, "note": "map_time_s: RoomPredictor.path_gain_db; load_time_s: read rf.h5 "
               "and build the BVH; python and torch start-up not included"}
        return _report(out, args.results)
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        fields, names = scene_from_mesh("classroom", args.spacing)
        write_scene_artifact(d / "scene.h5", fields, label_names=names)
        t, r = np.repeat(tx, len(rx), 0), np.tile(rx, (len(tx), 1))
        gain = 10 * np.log10(friis_path_gain(np.linalg.norm(r - t, axis=1), FREQ))
        write_artifact(d / "meas.h5", "measurements", {
            "tx_pos": t, "rx_pos": r, "freq_hz": np.array([FREQ]), "path_gain_db": gain[:, None],
            "split": np.zeros(len(t), np.int64), "tx_id": np.repeat(np.arange(len(tx)), len(rx)),
            "scene_bounds": bounds}, attrs={"task": "rssi", "scene": "classroom"})
        cfg = {"physical": {"iterations": 5, "start_iterations": 2}}
        t0 = time.time()
        rf_fit(d / "scene.h5", d / "meas.h5", d / "rf.h5", cfg)
        fit_s = time.time() - t0
        out = {"num_gaussians": int(len(fields["gaussians/means"])), "spacing_m": args.spacing, "num_points": len(rx),
               **_time_map(d / "rf.h5", rx, args.repeats), "fit_5_steps_s": fit_s, "budget_s": 2.0}
    _report(out, args.results)


def _time_map(rf_path: Path, rx: np.ndarray, repeats: int) -> dict:
    """Best-of-`repeats` load and map times for a new transmitter at (4.1, 3.3, 1.7) m."""
    new_tx = np.array([4.1, 3.3, 1.7])
    times = []
    for _ in range(repeats):
        t0 = time.time()
        pred = load_predictor(read_artifact(rf_path, "rf"))
        load_s = time.time() - t0
        t1 = time.time()
        pg = pred.path_gain_db(np.broadcast_to(new_tx, rx.shape), rx)
        times.append((load_s, time.time() - t1))
    load_s, map_s = (min(x) for x in zip(*times))
    return {"map_time_s": map_s, "load_time_s": load_s, "finite": bool(np.isfinite(pg).all())}


def _report(out: dict, results: Path | None) -> None:
    print(json.dumps(out, indent=1))
    Path(__file__).with_name("rssi.json").write_text(json.dumps(out, indent=1) + "\n")
    if results is not None:
        results.parent.mkdir(parents=True, exist_ok=True)
        results.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
