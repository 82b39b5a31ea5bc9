"""A links CSV of a measured survey, thinned for the reproduce workflow's `measured` target.

    python -m rfir_stages.reproduce.survey LINKS.csv OUT.csv [--every-tx K] [--drop-split]

Keeps the '#' set-up lines and the column header, and the links of every K-th transmitter (by
tx_id, in increasing order: the quick variant's every third beacon position); --drop-split leaves
out the `split` column, so that `rfir import csv --split PROTOCOL` can write another one.
"""
from __future__ import annotations

import argparse
import csv
import io
import sys
from pathlib import Path


def thin(text: str, every_tx: int = 1, drop_split: bool = False) -> tuple[str, int, int]:
    """(the CSV text kept, links kept, transmitters kept) of a links CSV's text."""
    if every_tx < 1:
        raise ValueError("--every-tx must be >= 1")
    lines = text.splitlines()
    head = [ln for ln in lines if ln.startswith("#")]
    body = [ln for ln in lines if ln.strip() and not ln.startswith("#")]
    rows = list(csv.reader(body))
    columns, rows = rows[0], rows[1:]
    if "tx_id" not in columns:
        raise ValueError("the links CSV has no tx_id column")
    it = columns.index("tx_id")
    ids = sorted({r[it] for r in rows}, key=lambda v: (float(v), v) if _number(v) else (float("inf"), v))
    keep_ids = set(ids[::every_tx])
    kept = [r for r in rows if r[it] in keep_ids]
    cols = list(range(len(columns)))
    if drop_split and "split" in columns:
        cols.remove(columns.index("split"))
    out = io.StringIO()
    w = csv.writer(out, lineterminator="\n")
    w.writerow([columns[c] for c in cols])
    for r in kept:
        w.writerow([r[c] for c in cols])
    note = [f"# reproduce: the links of every {every_tx}-th transmitter (tx_id) of the survey kept"] if every_tx > 1 else []
    return "\n".join(head + note) + "\n" + out.getvalue(), len(kept), len(keep_ids)


def _number(v: str) -> bool:
    try:
        float(v)
        return True
    except ValueError:
        return False


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m rfir_stages.reproduce.survey", description=__doc__,
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
