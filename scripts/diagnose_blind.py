"""A blind test of `rfir diagnose`: cases with hidden effects injected into copies of simulated data,
diagnosed without their answers, then scored (rfir_stages.diagnose.blind).

    python scripts/diagnose_blind.py make DATA [--quick]     # simulate (cached) and write the cases
    python scripts/diagnose_blind.py run DATA OUT [--quick]  # make if needed, diagnose, score

`run` writes OUT/diagnose_blind.{json,md} and prints the table.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rfir_stages.diagnose.blind import QUICK, make, run_set


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python scripts/diagnose_blind.py", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    m = sub.add_parser("make", help="simulate (cached) and write the cases and their answers")
    m.add_argument("data", type=Path)
    m.add_argument("--quick", action="store_true", help=f"only {', '.join(QUICK)}")
    r = sub.add_parser("run", help="make if needed, diagnose every case blind, then score")
    r.add_argument("data", type=Path)
    r.add_argument("out", type=Path)
    r.add_argument("--quick", action="store_true", help=f"only {', '.join(QUICK)}")
    a = p.parse_args(argv)
    if a.cmd == "make":
        make(a.data, a.quick)
        return 0
    run_set(a.data, a.out, a.quick)
    print((a.out / "diagnose_blind.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
