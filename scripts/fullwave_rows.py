"""Write the BEM curves of the full-wave check as turntable measurements and meshes for rfir.

    python scripts/fullwave_rows.py results/reproduce/fullwave/fullwave_vs_po.json OUT [--range 10]

For each case of the check (a 0.3 m PEC plate and a dihedral) writes OUT/<kind>.csv (a turntable
measurement for `rfir import csv`, the radar at --range m, even aspects `train` and odd `test`) and
OUT/<kind>.ply (the screen as a triangle mesh for `rfir mesh-gaussians`); see
rfir_stages.fullwave.rows. The commands that score rfir on them are in docs/results.md.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rfir_stages.fullwave.rows import write_rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python scripts/fullwave_rows.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("check", type=Path, help="fullwave_vs_po.json of scripts/fullwave_compare.py")
    ap.add_argument("out", type=Path)
    ap.add_argument("--range", type=float, default=10.0, dest="range_m", help="radar range, m")
    a = ap.parse_args(argv)
    try:
        written = write_rows(a.check, a.out, a.range_m)
    except KeyError as exc:
        print(f"error: fullwave rows {a.check}: no {exc} in the check's JSON", file=sys.stderr)
        return 2
    except (OSError, ValueError) as exc:
        print(f"error: fullwave rows {a.check}: {exc}", file=sys.stderr)
        return 2
    for csv_path, ply_path, aspects in written:
        print(f"wrote {csv_path} ({aspects} aspects) and {ply_path.name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
