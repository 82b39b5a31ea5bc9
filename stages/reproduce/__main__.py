"""Helpers the reproduce workflow (workflow/Snakefile) calls; `make reproduce*` runs the workflow.

    python -m rfir_stages.reproduce table TARGET [--quick] [--data DIR] [--out DIR] [--set KEY=VALUE]
    python -m rfir_stages.reproduce steps [TARGET...] [--quick] [--data DIR] [--out DIR] [--set KEY=VALUE]
    python -m rfir_stages.reproduce freqs MEASUREMENTS.h5 EVERY
    python -m rfir_stages.reproduce results-page [--out DIR] [--page PATH] [--write]

table: fill TARGET's table from its steps' results JSON and benchmark files and write
OUT/<target>.md, .csv, .png and OUT/<target>.json (rows, rfir lowest, wall time of every step).
steps: print the command line of every step (what the workflow would run). freqs: every EVERY-th
frequency of a measurements file, comma separated (for `rfir predict rcs --freqs`). results-page: the
results page (docs/results.md) from the tables in OUT, printed (--write: written to --page).
--set reproduce.<full|quick>.<key>=value overrides a size of configs/reproduce.toml.
"""
from __future__ import annotations

import argparse
import json
import sys
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from rfir_core.errors import RfirError

from .page import PAGE, results_page, write_results_page
from .plan import Plan, default_dirs, machine_record, reproduce_command
from .tables import Table, to_markdown, write_table
from .targets import TARGETS, declare


def write_target(name: str, quick: bool, data: Path | None, out: Path | None, overrides: list[str] = ()) -> list[Path]:
    """Fill one target's table from its results and write its files; returns their paths."""
    plan, tables = declare([name], quick, data, out, overrides)
    return write_target_files(plan, name, *tables[name])


def write_target_files(plan: Plan, name: str, table: Table, labels: list[str]) -> list[Path]:
    """OUT/<name>.md, .csv, .png (the table filled from the results) and OUT/<name>.json (rows where
    rfir is lowest, the wall time of every step from its benchmark file, and its provenance: the command
    that makes the table, the machine that wrote it and the date, which the results page shows)."""
    table = table.resolved()
    table.steps = [(label, plan.wall(label)) for label in labels]
    paths = write_table(table, plan.out, name)
    summary = {"title": table.title, "quick": plan.quick,
               "rfir_lowest": table.ours_lowest(),
               "step_s": {label: t for label, t in table.steps},
               "step_s_total": sum(t for _, t in table.steps if t is not None),
               "files": [str(p) for p in paths],
               "provenance": {"command": reproduce_command(name, plan.quick, plan.overrides, plan.data, plan.out),
                              "machine": machine_record(),
                              "date": datetime.now(timezone.utc).strftime("%Y-%m-%d")}}
    path = plan.out / f"{name}.json"
    path.write_text(json.dumps(summary, indent=1) + "\n")
    print(to_markdown(table))
    return [*paths, path]


def wideband_freqs(meas: Path, every: int) -> str:
    from rfir_core.artifacts import read_artifact

    f = np.asarray(read_artifact(meas, "measurements")["freq_hz"], np.float64)
    return ",".join(f"{x:.6g}" for x in f[::every])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m rfir_stages.reproduce", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    t = sub.add_parser("table", help="write one target's table from its results")
    t.add_argument("target", help=", ".join(TARGETS))
    s = sub.add_parser("steps", help="print the steps' command lines")
    s.add_argument("targets", nargs="*", help="default: all")
    for p in (t, s):
        p.add_argument("--quick", action="store_true", help="the reduced variant")
        p.add_argument("--data", type=Path, default=None, help="data and fits (default data/reproduce[-quick])")
        p.add_argument("--out", type=Path, default=None, help="tables, JSON, logs (default results/reproduce[-quick])")
        p.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                       help="reproduce.<full|quick>.<key>=value over configs/reproduce.toml")
    r = sub.add_parser("results-page", help="the results page from the tables in OUT")
    r.add_argument("--out", type=Path, default=None, help="the tables (default results/reproduce)")
    r.add_argument("--page", type=Path, default=PAGE, help="where the page lives, for its links (default %(default)s)")
    r.add_argument("--write", action="store_true", help="write the page to --page instead of printing it")
    f = sub.add_parser("freqs", help="every EVERY-th frequency of a measurements file")
    f.add_argument("measurements", type=Path)
    f.add_argument("every", type=int)
    a = ap.parse_args(argv)
    try:
        if a.cmd == "table":
            write_target(a.target, a.quick, a.data, a.out, a.overrides)
        elif a.cmd == "steps":
            plan, _ = declare(a.targets or list(TARGETS), a.quick, a.data, a.out, a.overrides)
            for step in plan.steps.values():
                print(f"{step.label}: {step.command}")
        elif a.cmd == "results-page":
            if a.write:
                write_results_page(a.out or default_dirs(False)[1], a.page)
            else:
                sys.stdout.write(results_page(a.out, a.page))
        else:
            print(wideband_freqs(a.measurements, a.every))
    except RfirError as exc:
        print(f"error: reproduce {a.cmd}: {exc}", file=sys.stderr)
        return getattr(exc, "exit_code", 1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
