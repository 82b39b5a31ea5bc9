"""Measured-like RSSI from a simulated one (rfir_stages.simulate.measured_like; docs/simulate.md): per-device gains,
unknown antenna patterns, fading, positions clear of objects, a floor plan with its placement error, three splits.

    python scripts/measured_like.py SIM_DIR OUT_DIR [--seed N] [--set simulate.measured_like.KEY=VALUE]

SIM_DIR: the output of `rfir simulate SCENE SIM_DIR` for a room scene with a floor plan (the `flat`). Prints the
files written; an error is one line on stderr, with the exit code of its RfirError.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python scripts/measured_like.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("sim_dir", type=Path, help="output folder of `rfir simulate SCENE` (rssi)")
    ap.add_argument("out_dir", type=Path, help="folder to write (measurement files, floorplan/, truth.json)")
    ap.add_argument("--seed", type=int, default=0, help="seed of every draw (default 0)")
    ap.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                    help="simulate.measured_like.<key>=value over configs/simulate.toml")
    a = ap.parse_args(argv)

    from rfir_core.config import resolve_config, to_toml
    from rfir_core.errors import RfirError
    from rfir_stages.simulate.measured_like import run

    try:
        config = resolve_config(overrides=a.overrides)
        written = run(a.sim_dir, a.out_dir, config.get("simulate", {}).get("measured_like", {}), a.seed,
                      to_toml(config))
    except RfirError as exc:
        print(f"error: measured_like: {exc}", file=sys.stderr)
        return getattr(exc, "exit_code", 1)
    for key, path in written.items():
        print(f"wrote {path} ({key})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
