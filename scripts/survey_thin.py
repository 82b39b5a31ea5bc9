"""Thin a measured survey's links CSV for the reproduce workflow's `measured` target.

    python scripts/survey_thin.py LINKS.csv OUT.csv [--every-tx K] [--drop-split]

Keeps the '#' set-up lines and the column header, and the links of every K-th transmitter (by
tx_id, in increasing order: the quick variant's every third beacon position); --drop-split leaves
out the `split` column, so that `rfir import csv --split PROTOCOL` can write another one. The
thinning itself is rfir_stages.reproduce.survey.thin.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from rfir_stages.reproduce.survey import thin


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python scripts/survey_thin.py", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("links", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--every-tx", type=int, default=1, help="keep every K-th transmitter (default 1: all)")
    ap.add_argument("--drop-split", action="store_true", help="leave out the split column")
    a = ap.parse_args(argv)
    try:
        text, n_links, n_tx = thin(a.links.read_text(), a.every_tx, a.drop_split)
    except (OSError, ValueError, IndexError) as exc:
        print(f"error: survey {a.links}: {exc}", file=sys.stderr)
        return 2
    a.out.parent.mkdir(parents=True, exist_ok=True)
    a.out.write_text(text)
    print(f"{a.out}: {n_links} links of {n_tx} transmitters" + (" (no split column)" if a.drop_split else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
