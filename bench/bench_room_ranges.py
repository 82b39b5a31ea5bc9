"""Benchmark of the room model's |Gamma(0)| ranges (rf_fit.room.reflection_ranges, docs/physics.md section 8.12):
the per-material evaluation (RoomLinks.material_part) against evaluating every fit link at each grid point, on
the same links in one process, and the largest difference of the two sets of ranges.

    .venv/bin/python bench/bench_room_ranges.py RF.h5 MEASUREMENTS.h5

RF.h5: a room model written by rf-fit; its fit links (training/fit_rows) are traced again from MEASUREMENTS.h5
and its fitted materials and system gain are the state the ranges start from (device gains left out: both
evaluations alike). Printed: materials, links, paths, wall and CPU seconds of each, then the two [N, 2] ranges.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from rfir_core.artifacts import read_artifact
from rfir_stages.model.fit_physical import _material_predictor, training_predictor
from rfir_stages.model.identifiability import normal_reflection_ranges
from rfir_stages.model.physical import MaterialParams
from rfir_stages.model.residual import SE_MARGIN
from rfir_stages.model.room import RoomPredictor


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("rf", help="a room model (rf artifact of rf-fit)")
    ap.add_argument("measurements", help="the measurements it was fitted to")
    args = ap.parse_args()
    rf, meas = read_artifact(args.rf, "rf"), read_artifact(args.measurements, "measurements")
    model = RoomPredictor(rf)
    rows = np.asarray(rf.free["training"]["fit_rows"])
    tx, rx = np.asarray(meas["tx_pos"])[rows], np.asarray(meas["rx_pos"])[rows]
    target = np.asarray(meas["path_gain_db"])[rows][:, :1]
    links = model.room.links(tx, rx, np.full(len(rows), model.freq_hz))
    m = model.mats
    n = len(m.eps_r)
    params = MaterialParams(n, shared_scattering=bool(np.allclose(m.scattering.numpy(), float(m.scattering[0]))))
    for i in range(n):
        params.set_values(i, eps_r=float(m.eps_r[i]), sigma_1ghz=float(m.sigma_1ghz[i]),
                          scattering=float(m.scattering[i]),
                          thickness_m=None if m.thickness_m is None else float(m.thickness_m[i]))
    with torch.no_grad():
        params.gain_db.fill_(float(model.gain_db))
    out, times = {}, {}
    for name, local in (("per material", _material_predictor(links, target, None)), ("every link", None)):
        c0, t0 = time.process_time(), time.time()
        out[name] = normal_reflection_ranges(training_predictor(links, target), params, target, model.freq_hz,
                                             margin=SE_MARGIN, local=local)
        times[name] = (time.time() - t0, time.process_time() - c0)
    print(f"{n} materials, {len(rows)} links, {links.paths.num} paths: " + ", ".join(
        f"{k} {w:.1f} s (CPU {c:.1f} s)" for k, (w, c) in times.items()))
    print(np.round(np.concatenate([out["per material"], out["every link"]], 1), 3))
    print(f"largest difference {np.abs(out['per material'] - out['every link']).max():.2e}")


if __name__ == "__main__":
    main()
