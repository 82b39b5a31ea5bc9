"""The "traditional ray tracing" baseline (issue 11): Sionna RT on a reconstructed mesh with a guessed
ITU material, predicting the links of an RSSI measurement file; scored on its test split.

    python scripts/baseline_raytrace.py MESH.ply MEASUREMENTS.h5 --material concrete --results results/NAME.json

MESH: e.g. `rfir geom`'s scene_mesh.ply (TSDF fusion of the photos). The whole mesh gets one material
(a mesh from photos carries no labels; the user guesses what most of the room is made of) and
Sionna's default physics of `rfir simulate` (configs/simulate.toml). A baseline, not a stage: it
reads and writes no artifact other than its JSON.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("mesh")
    ap.add_argument("measurements")
    ap.add_argument("--material", default="concrete")
    ap.add_argument("--thickness", type=float, default=0.2, help="slab thickness Sionna assumes, m")
    ap.add_argument("--results", required=True)
    a = ap.parse_args(argv)

    from rfir_core.artifacts import read_artifact
    from rfir_core.progress import NullProgress
    from rfir_stages.geom.mesh_io import read_ply_mesh
    from rfir_stages.simulate.radio_scene import load_radio_scene
    from rfir_stages.simulate.rssi import simulate_rssi
    from rfir_stages.simulate.scenes import SceneObject, SceneSpec
    from rfir_stages.simulate.settings import parse_settings

    t0 = time.time()
    meas = read_artifact(a.measurements, "measurements")
    tx_all, rx_all = np.asarray(meas["tx_pos"]), np.asarray(meas["rx_pos"])
    tx_id, rx_id = np.asarray(meas["tx_id"]), np.asarray(meas["rx_id"])
    tx = np.stack([tx_all[np.flatnonzero(tx_id == i)[0]] for i in range(tx_id.max() + 1)])
    rx = np.stack([rx_all[np.flatnonzero(rx_id == i)[0]] for i in range(rx_id.max() + 1)])
    freqs = np.asarray(meas["freq_hz"], np.float64)[:1]
    mesh = read_ply_mesh(a.mesh)
    obj = SceneObject("reconstructed", 0, np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int32),
                      a.material, "plaster", (0.8, 0.8, 0.8), a.thickness)
    spec = SceneSpec("reconstructed", "room", [obj], np.stack([mesh.vertices.min(0), mesh.vertices.max(0)]))
    settings = parse_settings(None)
    work = Path(a.results).with_suffix("")
    radio = load_radio_scene(spec, work.parent / (work.name + "_radio"), float(freqs[0]), settings.material_effects())
    t_solve = time.time()
    _, power, sim_tx, sim_rx, _, _ = simulate_rssi(radio, tx, rx, freqs, settings.physics_for("rssi"), NullProgress(),
                                                     "ray tracing")
    solve_s = time.time() - t_solve
    pred = 10 * np.log10(np.maximum(power[:, 0], 1e-25))          # no path: -250 dB
    table = {(int(t), int(r)): i for i, (t, r) in enumerate(zip(sim_tx, sim_rx))}
    order = np.array([table[(int(t), int(r))] for t, r in zip(tx_id, rx_id)])
    pred = pred[order]
    y = np.asarray(meas["path_gain_db"], np.float64)[:, 0]
    test = np.asarray(meas["split"]) == 1
    out = {"method": f"Sionna RT on {a.mesh}, one guessed material ({a.material}, {a.thickness} m), simulate's "
                     "default physics", "mesh_triangles": int(len(mesh.faces)),
           "measurements": a.measurements, "num_test": int(test.sum()),
           "mae_db": float(np.mean(np.abs(pred[test] - y[test]))),
           "mae_all_db": float(np.mean(np.abs(pred - y))), "links_without_path": int(np.sum(pred <= -240)),
           "solve_s": solve_s, "wall_s": time.time() - t0}
    Path(a.results).parent.mkdir(parents=True, exist_ok=True)
    Path(a.results).write_text(json.dumps(out, indent=2) + "\n")
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
