"""Validate an edit against the independent simulator (stages/edit/validate.py; docs/guide/edit.md): apply the
edit to a fit of the unedited scene with `rfir edit`, predict both scenes' measured links and compare, as the
reproduce workflow's edit table does.

    python scripts/edit_validate.py RF BEFORE.h5 AFTER.h5 --select S --op O [...] --name NAME
        [--results results/NAME.json] [--plots DIR] [--work DIR]

Prints the figures (MAE unedited / edited / not edited, the change correlations) as JSON.
"""
from __future__ import annotations

import argparse
import json


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("rf")
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("--select", action="append", required=True)
    ap.add_argument("--op", action="append", required=True)
    ap.add_argument("--name", required=True)
    ap.add_argument("--results")
    ap.add_argument("--plots")
    ap.add_argument("--work", default="runs/edit_validation")
    a = ap.parse_args(argv)

    from rfir_stages.edit.validate import validate

    out = validate(a.rf, a.before, a.after, a.select, a.op, a.name, a.work, a.results, a.plots)
    print(json.dumps({k: v for k, v in out.items() if not isinstance(v, list)}, indent=2))


if __name__ == "__main__":
    main()
