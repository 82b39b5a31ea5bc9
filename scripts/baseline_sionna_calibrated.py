"""Ray tracing with calibrated materials (baseline): Sionna RT on a mesh, one radio material per object
class, eps_r and sigma fitted to training links through Sionna's differentiable path solver.

    python scripts/baseline_sionna_calibrated.py MESH.ply MEASUREMENTS.h5 --split random|holdout_tx
        --results results/NAME.json [--iterations 40] [--links 400] [--tx-per-step 4] [--depth D]
        [--samples N] [--lr 0.1] [--lr-decay 0.1] [--material concrete] [--thickness 0.2]
        [--learn-thickness] [--seed 0]

The method, its settings and the results file: rfir_stages.baselines.sionna_calibrated and
docs/baselines.md. Prints the progress, then the test and training MAE and the fitted materials.
"""
from __future__ import annotations

import argparse
import sys

from rfir_core.errors import RfirError
from rfir_stages.baselines.sionna_calibrated import SPLITS, CalibSettings, run


def main(argv: list[str] | None = None) -> int:
    d = CalibSettings()
    ap = argparse.ArgumentParser(prog="python scripts/baseline_sionna_calibrated.py",
                                 description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("mesh", help="PLY mesh (face labels + labels.json: one material per class; else one material)")
    ap.add_argument("measurements", help="RSSI measurements artifact (rfir simulate)")
    ap.add_argument("--split", choices=SPLITS, default="random")
    ap.add_argument("--results", required=True)
    ap.add_argument("--material", default=d.material, help="guessed ITU material every class starts from")
    ap.add_argument("--thickness", type=float, default=d.thickness_m, help="slab thickness at the start, m")
    ap.add_argument("--learn-thickness", action="store_true", help="calibrate each class's slab thickness too")
    ap.add_argument("--iterations", type=int, default=d.iterations)
    ap.add_argument("--lr", type=float, default=d.lr)
    ap.add_argument("--lr-decay", type=float, default=d.lr_decay, help="last step size / first")
    ap.add_argument("--links", type=int, default=d.links, help="training links in the calibration subsample")
    ap.add_argument("--tx-per-step", type=int, default=d.tx_per_step)
    ap.add_argument("--depth", type=int, default=d.max_depth,
                    help="bounces of the calibration solves (default: the prediction's, configs/simulate.toml)")
    ap.add_argument("--samples", type=int, default=d.samples_per_src, help="rays per transmitter of the calibration "
                    "solves (default: the prediction's)")
    ap.add_argument("--seed", type=int, default=d.seed)
    a = ap.parse_args(argv)
    s = CalibSettings(material=a.material, thickness_m=a.thickness, iterations=a.iterations, lr=a.lr,
                      lr_decay=a.lr_decay, learn_thickness=a.learn_thickness, links=a.links,
                      tx_per_step=a.tx_per_step, max_depth=a.depth,
                      samples_per_src=a.samples, seed=a.seed)
    try:
        out = run(a.mesh, a.measurements, a.split, a.results, s, say=lambda m: print(m, flush=True))
    except RfirError as exc:
        print(f"error: sionna-calibrated: {exc}", file=sys.stderr)
        return getattr(exc, "exit_code", 1)
    m = out["metrics"]
    print(f"sionna-calibrated: test MAE {m['mae_db']:.3f} dB, train MAE {m['mae_train_db']:.3f} dB "
          f"({m['num_test']} test links), {out['wall_time_s']:.0f} s; results {a.results}")
    for c, v in out["materials"].items():
        print(f"  {c:16s} eps_r {v['eps_r']:7.3f}  sigma {v['sigma_s_per_m']:.4g} S/m  "
              f"thickness {v['thickness_m']:.4g} m")
    return 0


if __name__ == "__main__":
    sys.exit(main())
