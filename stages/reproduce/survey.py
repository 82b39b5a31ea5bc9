"""A links CSV of a measured survey, thinned for the reproduce workflow's `measured` target
(command line: scripts/survey_thin.py).

`thin` keeps the '#' set-up lines and the column header, and the links of every K-th transmitter (by
tx_id, in increasing order: the quick variant's every third beacon position); drop_split leaves
out the `split` column, so that `rfir import csv --split PROTOCOL` can write another one.
"""
from __future__ import annotations

import csv
import io


def thin(text: str, every_tx: int = 1, drop_split: bool = False) -> tuple[str, int, int]:
    """(the CSV text kept, links kept, transmitters kept) of a links CSV's text."""
    if every_tx < 1:
        raise ValueError(f"every_tx must be >= 1, not {every_tx}")
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
