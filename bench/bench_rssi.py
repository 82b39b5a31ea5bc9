"""Benchmark of `predict rssi` (issue 23): radio maps for new transmitters in the classroom.

    .venv/bin/python bench/bench_rssi.py                       # furniture-resolving surfels (0.8 m, size / 12, rectangles)
    .venv/bin/python bench/bench_rssi.py --object-cells 0      # uniform 0.8 m surfels
    .venv/bin/python bench/bench_rssi.py --rf rf.h5 --results results/classroom_rssi_speed.json   # a fitted model

Needs no simulator: the classroom's meshes are built by code (rfir_stages.simulate.scenes) and tiled as
`rfir mesh-gaussians classroom_gt.ply --spacing 0.8 --object-cells 12 --rectangles --drop-contact-faces`
tiles them; a 5-step fit of the room model on free-space data for two transmitters gives an `rf` artifact.
Then, median of `--repeats`:
- map_cold_s: a 440-point map (22 x 20 receivers at 1 m) with nothing kept: the surfaces crossed from
  every receiver to the diffuse cells it needs traced (room_diffuse.CellCrossings), and map_cold_cpu_s its
  CPU time; the paths are traced on a second thread meanwhile (RoomGeometry.links);
- map_new_tx_s: a map of the same receivers for a transmitter not seen before, the receivers kept from
  an earlier map of the same model (RoomGeometry.cell_crossings);
- default_map_s: `predict rssi --tx ... --grid` 's default map ([predict.rssi] grid) from a freshly
  loaded model, whose receivers rf-fit stored (rf_fit.room.map_visibility);
- the higher orders' share: the same new-transmitter map with rf_fit.room.max_order = 1.
The budget in the issue: 2 s on the 2-core CPU. Prints the timings, the load average they ran under,
and writes bench/rssi.json.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from rfir_core.artifacts import read_artifact, write_artifact
from rfir_core.physics.closed_forms import friis_path_gain
from rfir_stages.geom import write_scene_artifact
from rfir_stages.predict.rssi import rssi_defaults
from rfir_stages.predict.rssi_checks import floor_grid
from rfir_stages.predict.rssi_model_io import load_predictor
from rfir_stages.rf_fit.stage import run as rf_fit
from rfir_stages.simulate.rssi import grid_positions

FREQ = 2.4e9
NEW_TX = np.array([[4.1, 3.3, 1.7], [6.0, 2.0, 2.2], [2.5, 5.1, 2.0], [7.2, 4.4, 1.5], [3.3, 1.2, 2.4]])


def classroom_fields(spacing_m: float, object_cells: int):
    """Surfels of the code-built classroom as `mesh-gaussians --spacing --object-cells` tiles its mesh, with
    `--rectangles --drop-contact-faces` where object_cells > 0 (mesh-gaussians --preset room)."""
    from rfir_stages.geom.from_mesh import scene_triangles
    from rfir_stages.geom.mesh_io import Mesh, object_spacings, surfels_per_object, without_contact_faces

    verts, faces, labels, names = scene_triangles("classroom")
    mesh = Mesh(verts, faces, labels, dict(enumerate(names)))
    if object_cells > 0:
        mesh = without_contact_faces(mesh)[0]
    return surfels_per_object(mesh, object_spacings(mesh, spacing_m, object_cells), rectangles=object_cells > 0), names


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--spacing", type=float, default=0.8, help="surfel spacing [m]")
    ap.add_argument("--object-cells", type=int, default=12, help="objects at min(spacing, size / N); 0: uniform")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--rf", type=Path, help="time this fitted RSSI model instead of a 5-step synthetic fit")
    ap.add_argument("--results", type=Path, help="also write the figures to this JSON")
    args = ap.parse_args()
    bounds = np.array([[0.0, 0.0, 0.0], [9.0, 7.0, 3.0]])
    rx = grid_positions(bounds, 22, 20, 1.0, 0.4)
    if args.rf is not None:
        rf = read_artifact(args.rf, "rf")
        out = {"rf": str(args.rf), "num_gaussians": int(len(rf["rf/opacity"])),
               **_time_maps(args.rf, rx, args.repeats),
               "fit_s": float(rf.free["training@attrs"]["wall_time_s"]),
               "fit_trace_s": float(rf.free["training@attrs"]["trace_time_s"])}
        return _report(out, args.results)
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        fields, names = classroom_fields(args.spacing, args.object_cells)
        write_scene_artifact(d / "scene.h5", fields, label_names=names)
        tx = np.array([[2.4, 2.7, 2.2], [6.6, 4.3, 2.2]])
        t, r = np.repeat(tx, len(rx), 0), np.tile(rx, (len(tx), 1))
        gain = 10 * np.log10(friis_path_gain(np.linalg.norm(r - t, axis=1), FREQ))
        write_artifact(d / "meas.h5", "measurements", {
            "tx_pos": t, "rx_pos": r, "freq_hz": np.array([FREQ]), "path_gain_db": gain[:, None],
            "split": np.zeros(len(t), np.int64), "tx_id": np.repeat(np.arange(len(tx)), len(rx)),
            "scene_bounds": bounds}, attrs={"task": "rssi", "scene": "classroom"})
        t0 = time.time()
        rf_fit(d / "scene.h5", d / "meas.h5", d / "rf.h5", {"physical": {"iterations": 5, "start_iterations": 2}})
        fit_s = time.time() - t0
        out = {"num_gaussians": int(len(fields["gaussians/means"])), "spacing_m": args.spacing,
               "object_cells": args.object_cells, **_time_maps(d / "rf.h5", rx, args.repeats),
               "fit_5_steps_s": fit_s}
    _report(out, args.results)


def _time_maps(rf_path: Path, rx: np.ndarray, repeats: int) -> dict:
    """Medians of `repeats` runs (module docstring); each map is RoomPredictor.path_gain_db alone."""
    def timed(fn, *a):
        t0 = time.perf_counter()
        value = fn(*a)
        return time.perf_counter() - t0, value

    def tx_of(i):
        return np.broadcast_to(NEW_TX[i % len(NEW_TX)], rx.shape)

    load, cold, cold_cpu, new_tx, first_order, default = [], [], [], [], [], []
    pred = load_predictor(read_artifact(rf_path, "rf"))
    means = pred.geom.means.numpy()
    grid = floor_grid((means.min(0), means.max(0)), *rssi_defaults()["grid"])
    for i in range(repeats):
        t, pred = timed(load_predictor, read_artifact(rf_path, "rf"))
        load.append(t)
        default.append(timed(pred.path_gain_db, np.broadcast_to(NEW_TX[0], grid.shape), grid)[0])
        pred.room.cell_crossings.clear()                       # nothing kept: every receiver traced
        c0 = time.process_time()
        cold.append(timed(pred.path_gain_db, tx_of(i), rx)[0])
        cold_cpu.append(time.process_time() - c0)
        t, pg = timed(pred.path_gain_db, tx_of(i + 1), rx)           # the receivers kept from the map above
        new_tx.append(t)
        finite = bool(np.isfinite(pg).all())
    pred.room.settings.max_order = 1
    for i in range(repeats):
        first_order.append(timed(pred.path_gain_db, tx_of(i + 2), rx)[0])
    med = statistics.median
    return {"num_points": len(rx), "default_map_points": len(grid), "load_time_s": med(load),
            "map_cold_s": med(cold), "map_cold_cpu_s": med(cold_cpu), "map_new_tx_s": med(new_tx),
            "map_new_tx_first_order_s": med(first_order),
            "higher_order_share_s": med(new_tx) - med(first_order), "default_map_s": med(default),
            "finite": finite, "budget_s": 2.0, "repeats": repeats, "load_average_1min": os.getloadavg()[0],
            "note": "medians; map times: RoomPredictor.path_gain_db alone; load_time_s: read rf.h5, patches, "
                    "cells and the BVH; python and torch start-up not included; map_cold_cpu_s: the process's CPU "
                    "time of the cold map (both threads; less sensitive than the wall time to other jobs on the CPU)"}


def _report(out: dict, results: Path | None) -> None:
    print(json.dumps(out, indent=1))
    Path(__file__).with_name("rssi.json").write_text(json.dumps(out, indent=1) + "\n")
    if results is not None:
        results.parent.mkdir(parents=True, exist_ok=True)
        results.write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
