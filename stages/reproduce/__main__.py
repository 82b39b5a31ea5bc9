"""CLI of the reproduce targets (see the package docstring); `make reproduce*` calls it."""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from rfir_cli.errors import RfirError

from .runner import Runner
from .tables import to_markdown, write_table
from .targets import TARGETS


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m rfir_stages.reproduce", description=__doc__)
    ap.add_argument("targets", nargs="+", help=f"{', '.join(TARGETS)} or all")
    ap.add_argument("--quick", action="store_true", help="reduced sizes: checks the chain in minutes")
    ap.add_argument("--data", type=Path, default=None, help="data and fits (default data/reproduce[-quick])")
    ap.add_argument("--out", type=Path, default=None, help="tables, logs, times (default results/reproduce[-quick])")
    ap.add_argument("--force", action="store_true", help="rerun steps whose outputs exist")
    a = ap.parse_args(argv)
    names = list(TARGETS) if "all" in a.targets else a.targets
    unknown = [n for n in names if n not in TARGETS]
    if unknown:
        print(f"error: unknown target {unknown[0]!r} (known: {', '.join(TARGETS)}, all)", file=sys.stderr)
        return 2
    suffix = "-quick" if a.quick else ""
    runner = Runner(a.data or Path(f"data/reproduce{suffix}"), a.out or Path(f"results/reproduce{suffix}"),
                    quick=a.quick, force=a.force)
    summary_path = runner.out / "summary.json"
    summary: dict = {}
    for name in names:
        t0 = time.perf_counter()
        try:
            table = TARGETS[name](runner)
        except RfirError as exc:
            print(f"error: reproduce {name}: {exc}", file=sys.stderr)
            return getattr(exc, "exit_code", 1)
        paths = write_table(table, runner.out, name)
        wall = time.perf_counter() - t0
        steps = {k: v for k, v in runner.times.items() if k in runner.used}
        summary[name] = {"wall_s_this_run": wall, "step_s_total": sum(steps.values()), "steps": steps,
                         "rfir_lowest": table.ours_lowest(), "files": [str(p) for p in paths]}
        runner.used.clear()
        on_disk = json.loads(summary_path.read_text()) if summary_path.exists() else {}
        summary = {**on_disk, name: summary[name]}     # other targets may have finished meanwhile
        summary_path.write_text(json.dumps(summary, indent=1) + "\n")
        print(to_markdown(table))
        print(f"reproduce {name}: {wall / 60:.1f} min this run ({sum(steps.values()) / 60:.1f} min of steps "
              f"incl. cached) -> {', '.join(str(p) for p in paths)}")
    if runner.failed:
        print("error: " + str(len(runner.failed)) + " baseline step(s) failed:\n  " + "\n  ".join(runner.failed),
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
