"""Benchmark of the physical model (issues 22, 23): rf-fit and `predict rcs` on the lego demo.

    .venv/bin/python bench/bench_physical.py                        # the demo's lego (make demo first)
    .venv/bin/python bench/bench_physical.py --repeats 3 --fit-repeats 3
    .venv/bin/python bench/bench_physical.py --scene S.h5 --measurements M.h5 --results out.json   # other data

Runs rf-fit (seed 0) and `predict rcs` on the measured rows the way the CLI does (configs/*.toml through
the config loader; python and torch start-up not included) and prints the median wall times with
the fit's own split (trace, model selection, refit, residual). Without the demo's data (DEMO, default
demo_out, from `make demo`) it says so and skips. Writes bench/physical.json.
"""
from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

from rfir_core.artifacts import read_artifact
from rfir_core.config import resolve_config
from rfir_stages.predict import run_rcs
from rfir_stages.rf_fit.stage import run as rf_fit

SPLIT_KEYS = ("trace_time_s", "select_time_s", "refit_time_s", "residual_time_s")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scene", type=Path, default=Path("demo_out/scene.h5"), help="photo Gaussians (scene artifact)")
    ap.add_argument("--measurements", type=Path, default=Path("demo_out/lego/measurements.h5"))
    ap.add_argument("--repeats", type=int, default=3, help="predict repeats (median)")
    ap.add_argument("--fit-repeats", type=int, default=1, help="rf-fit repeats (median)")
    ap.add_argument("--results", type=Path, help="also write the figures to this JSON")
    args = ap.parse_args()
    missing = [str(p) for p in (args.scene, args.measurements) if not p.exists()]
    if missing:
        print(f"bench_physical: skipped: {', '.join(missing)} missing (run `make demo` first, or pass --scene and "
              "--measurements)")
        return
    config = resolve_config()
    with tempfile.TemporaryDirectory() as tmp:
        rf_path = Path(tmp) / "rf.h5"
        fits = []
        for _ in range(max(1, args.fit_repeats)):
            t0 = time.time()
            rf_fit(args.scene, args.measurements, rf_path, dict(config.get("rf_fit", {})), seed=0)
            attrs = read_artifact(rf_path, "rf").free["training@attrs"]
            fits.append({"wall_s": time.time() - t0, **{k: float(attrs[k]) for k in SPLIT_KEYS if k in attrs}})
        preds = []
        for _ in range(max(1, args.repeats)):
            t0 = time.time()
            r = run_rcs(rf_path, Path(tmp) / "p.h5", dict(config.get("predict", {})), measurements_path=args.measurements,
                        results_path=Path(tmp) / "p.json")
            preds.append(time.time() - t0)
        rf = read_artifact(rf_path, "rf")
        out = {"scene": str(args.scene), "measurements": str(args.measurements),
               "num_gaussians": int(len(rf["gaussians/means"])), "predict_links": int(r.num_links),
               "freqs_hz": [float(f) for f in r.freqs_hz],
               "predict_s": statistics.median(preds), "predict_runs_s": preds,
               "fit_s": statistics.median(f["wall_s"] for f in fits),
               **{f"fit_{k}": statistics.median(f[k] for f in fits) for k in SPLIT_KEYS if k in fits[0]},
               "note": "median wall times; rf-fit and predict rcs as the CLI runs them, without python and torch "
                       "start-up; the fit's split as rf-fit records it in the artifact"}
    text = json.dumps(out, indent=1)
    print(text)
    Path(__file__).with_name("physical.json").write_text(text + "\n")
    if args.results is not None:
        args.results.parent.mkdir(parents=True, exist_ok=True)
        args.results.write_text(text + "\n")


if __name__ == "__main__":
    main()
