"""Full-wave check of the PO backend: BEM (EFIE, bempp-cl) against `rfir_stages.po` on a 0.3 m PEC plate
and a dihedral, monostatic, far field, 2.4 GHz, V polarisation, aspects in the x-y plane.

    python scripts/fullwave_compare.py --out results/fullwave [--aspects 360] [--plate-n 24] [--dihedral-n 17]

Writes OUT/fullwave_vs_po.json (curves, gaps by region, timings) and OUT/fullwave_vs_po.png
(rfir_stages.fullwave.compare) and prints each case's closed-form check, gaps and timings.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from rfir_stages.fullwave.compare import write_check


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python scripts/fullwave_compare.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--aspects", type=int, default=360)
    ap.add_argument("--plate-n", type=int, default=24, help="quads per plate side (24: edges lambda/10 at 2.4 GHz)")
    ap.add_argument("--dihedral-n", type=int, default=17, help="quads per side of each dihedral face")
    a = ap.parse_args(argv)
    command = (f"python scripts/fullwave_compare.py --out {a.out} --aspects {a.aspects} --plate-n {a.plate_n} "
               f"--dihedral-n {a.dihedral_n}")
    cases = write_check(a.out, a.aspects, a.plate_n, a.dihedral_n, command)
    for c in cases:
        print(c["kind"], json.dumps({k: c[k] for k in ("broadside", "bisector", "timings", "regions") if k in c}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
