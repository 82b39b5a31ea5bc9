"""Benchmark: `predict rcs` of 360 aspects from a fitted lego (issue 7 target: within 5 s on this CPU).

Usage: python bench/bench_predict_rcs.py [RF_H5]   (default: a small fit made here, ~1 min)
Prints the median of 3 runs of predicting 360 aspects at 3 m with culling (config default) and
without, and the largest difference between the two in dB.
"""
from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from rfir_cli.artifacts import read_artifact
from rfir_stages.predict.rcs import predict_path_gain_db
from rfir_stages.rf_fit.links import geometry_from_artifact, radar_links, scene_centre


def _fit_small_lego(folder: Path) -> Path:
    """A lego fit on synthetic measurements (the renderer's own output), 30 steps: enough for timing."""
    from rfir_stages.geom import scene_from_mesh, write_scene_artifact
    from rfir_stages.rf_fit import run

    scene = folder / "scene.h5"
    fields, labels = scene_from_mesh("lego", 0.03)
    write_scene_artifact(scene, fields, label_names=labels)
    meas = folder / "measurements.h5"
    _synthetic_measurements(scene, meas)
    out = folder / "rf.h5"
    run(scene, meas, out, {"iterations": 30})
    return out


def _synthetic_measurements(scene: Path, out: Path) -> None:
    from rfir_cli.artifacts import write_artifact

    art = read_artifact(scene, "scene")
    geom = geometry_from_artifact(art)
    centre = scene_centre(geom).numpy()
    asp = np.radians(np.arange(0.0, 360.0, 4.0))
    tx, rx, a, r = radar_links(asp, np.array([3.0]), centre)
    lo, hi = geom.means.min(0).values.numpy() - 0.1, geom.means.max(0).values.numpy() + 0.1
    pg = -60.0 + 5.0 * np.cos(3 * a)[:, None]
    write_artifact(out, "measurements", {
        "tx_pos": tx, "rx_pos": rx, "freq_hz": np.array([2.4e9]), "path_gain_db": pg,
        "channel": (10 ** (pg / 20)).astype(np.complex128), "split": (np.arange(len(a)) % 2).astype(np.int64),
        "tx_id": np.arange(len(a)), "rx_id": np.arange(len(a)), "scene_bounds": np.stack([lo, hi]),
        "rcs_dbsm": pg + 30.0, "aspect_rad": a, "range_m": r}, attrs={"task": "rcs", "scene": "lego"})


def main() -> None:
    torch.set_num_threads(max(1, torch.get_num_threads()))
    with tempfile.TemporaryDirectory() as tmp:
        rf_path = Path(sys.argv[1]) if len(sys.argv) > 1 else _fit_small_lego(Path(tmp))
        rf = read_artifact(rf_path, "rf")
        geom = geometry_from_artifact(rf)
        tx, rx, _, _ = radar_links(np.radians(np.arange(0.0, 360.0, 1.0)), np.array([3.0]),
                                   scene_centre(geom).numpy())
        freqs = np.asarray(rf["rf/freq_hz"])[:1]
        results = {}
        for cull in (1e-3, 0.0):
            times, out = [], None
            for _ in range(3):
                t0 = time.perf_counter()
                out = predict_path_gain_db(rf, tx, rx, freqs, "rcs", cull_rel=cull)
                times.append(time.perf_counter() - t0)
            results[cull] = (statistics.median(times), out)
            print(f"predict 360 aspects, {geom.num} Gaussians, cull_rel={cull:g}: median {results[cull][0]:.2f} s "
                  f"(runs {', '.join(f'{t:.2f}' for t in times)}; {torch.get_num_threads()} threads)")
        diff = np.abs(results[1e-3][1] - results[0.0][1])
        print(f"culling speed-up {results[0.0][0] / results[1e-3][0]:.2f}x; max |difference| {diff.max():.3f} dB, "
              f"mean {diff.mean():.4f} dB")


if __name__ == "__main__":
    main()
