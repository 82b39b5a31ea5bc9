"""Result tables of the reproduce targets: Markdown, CSV and a bar chart, shaped like the paper's.

A table has rows (a data set and protocol) and method columns; each cell is an MAE in dB, or a
note where a method cannot run (e.g. "unsupported: cannot edit"). The lowest MAE of a row is bold
in Markdown, and each method's wall time is kept beside its MAE. A target declares its table before
its steps ran: a row label or cell may be a function that reads the results, called by `resolved()`.
"""
from __future__ import annotations

import csv
import math
import textwrap
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

from rfir_core.figures import pyplot, save_figure


@dataclass
class Cell:
    """One method on one row: mae_db (None when not run), wall_s (None when unknown), note."""

    mae_db: float | None = None
    wall_s: float | None = None
    note: str = ""


@dataclass
class Table:
    """title; methods (column order); rows: (label, {method: Cell}); notes: lines under the table (a note may be
    a function that reads the results, as a deferred label)."""

    title: str
    methods: list[str]
    rows: list[tuple[str, dict[str, Cell]]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    ours: str = "rfir"
    steps: list[tuple[str, float | None]] = field(default_factory=list)   # (step label, wall s) of the target

    def add(self, label: str | Callable[[], str], cells: dict[str, Cell | Callable[[], Cell]]) -> None:
        self.rows.append((label, cells))

    def resolved(self) -> "Table":
        """A copy with every deferred label and cell read (from the steps' results)."""
        rows = [(label() if callable(label) else label, {m: c() if callable(c) else c for m, c in cells.items()})
                for label, cells in self.rows]
        notes = [n() if callable(n) else n for n in self.notes]
        return Table(self.title, list(self.methods), rows, notes, self.ours, list(self.steps))

    def best(self, cells: dict[str, Cell]) -> str | None:
        """The method with the lowest MAE on a row (None if no method has one)."""
        scored = [(c.mae_db, m) for m, c in cells.items() if c.mae_db is not None and math.isfinite(c.mae_db)]
        return min(scored)[1] if scored else None

    def ours_lowest(self) -> list[tuple[str, bool]]:
        """(row label, whether rfir's MAE is the lowest of the row) for rows where rfir ran."""
        out = []
        for label, cells in self.rows:
            if self.ours in cells and cells[self.ours].mae_db is not None:
                out.append((label, self.best(cells) == self.ours))
        return out


def _fmt(cell: Cell | None, bold: bool) -> str:
    if cell is None:
        return ""
    if cell.mae_db is None:
        return cell.note or "not run"
    text = f"{cell.mae_db:.2f}"
    return f"**{text}**" if bold else text


def _fmt_time(cell: Cell | None) -> str:
    if cell is None or cell.wall_s is None:
        return ""
    return f"{cell.wall_s / 60:.1f}" if cell.wall_s >= 60 else f"{cell.wall_s / 60:.2f}"


def to_markdown(table: Table) -> str:
    """The MAE table (lowest per row in bold), the wall-time table, then the notes."""
    head = "| row | " + " | ".join(table.methods) + " |"
    rule = "|---|" + "---|" * len(table.methods)
    lines = [f"## {table.title}", "", "MAE in dB (lowest of each row in bold):", "", head, rule]
    for label, cells in table.rows:
        best = table.best(cells)
        lines.append(f"| {label} | " + " | ".join(_fmt(cells.get(m), m == best) for m in table.methods) + " |")
    lines += ["", "Wall time per method (minutes; data generation not included; empty: cached or not run):", "",
              head, rule]
    for label, cells in table.rows:
        lines.append(f"| {label} | " + " | ".join(_fmt_time(cells.get(m)) for m in table.methods) + " |")
    lowest = table.ours_lowest()
    if lowest:
        won = sum(ok for _, ok in lowest)
        lines += ["", f"{table.ours} lowest on {won} of {len(lowest)} rows"
                  + ("" if won == len(lowest) else
                     " (not on: " + "; ".join(lbl for lbl, ok in lowest if not ok) + ")") + "."]
    if table.notes:
        lines += [""] + [f"- {n}" for n in table.notes]
    if table.steps:
        total = sum(t for _, t in table.steps if t is not None)
        lines += ["", f"Steps of this target (wall time from Snakemake's benchmark files; {total / 60:.1f} min in all, "
                  "shared steps counted in every target that uses them):", "", "| step | minutes |", "|---|---|"]
        lines += [f"| {label} | {'' if t is None else f'{t / 60:.2f}'} |" for label, t in table.steps]
    return "\n".join(lines) + "\n"


def write_csv(table: Table, path: Path) -> Path:
    """One line per (row, method): row, method, mae_db, wall_s, note."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["row", "method", "mae_db", "wall_s", "note"])
        for label, cells in table.rows:
            for m in table.methods:
                c = cells.get(m, Cell(note="not run"))
                w.writerow([label, m, "" if c.mae_db is None else f"{c.mae_db:.4f}",
                            "" if c.wall_s is None else f"{c.wall_s:.1f}", c.note])
    return path


def plot_table(table: Table, path: Path) -> Path:
    """Grouped bars: MAE per method for each row (methods without a number on any row are left out, bars
    and legend)."""
    plt = pyplot()
    methods = [m for m in table.methods
               if any(cells.get(m) is not None and cells[m].mae_db is not None for _, cells in table.rows)]
    n_rows, n_m = len(table.rows), len(methods)
    fig, ax = plt.subplots(figsize=(max(6.0, 1.3 * n_rows * max(1, n_m) / 3), 4.0))
    width = 0.8 / max(1, n_m)
    top = 0.0
    for j, m in enumerate(methods):
        xs, ys = [], []
        for i, (_, cells) in enumerate(table.rows):
            c = cells.get(m)
            if c is not None and c.mae_db is not None:
                xs.append(i - 0.4 + width * (j + 0.5))
                ys.append(c.mae_db)
                if math.isfinite(c.mae_db):
                    top = max(top, c.mae_db)
        ax.bar(xs, ys, width, label=m, edgecolor="black" if m == table.ours else None)
    if top > 0:
        ax.set_ylim(0, 1.3 * top)                       # room for the legend above the bars
    ax.set_xticks(range(n_rows))
    ax.set_xticklabels([textwrap.fill(label, 40) for label, _ in table.rows], rotation=20, ha="right", fontsize=8)
    ax.set_ylabel("MAE (dB)")
    ax.set_title(table.title, fontsize=10)
    ax.legend(fontsize=7, ncol=min(n_m, 4))
    ax.grid(axis="y", alpha=0.3)
    return save_figure(fig, path)


def write_table(table: Table, out: Path, name: str) -> list[Path]:
    """OUT/<name>.md, .csv and .png."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    md = out / f"{name}.md"
    md.write_text(to_markdown(table))
    return [md, write_csv(table, out / f"{name}.csv"), plot_table(table, out / f"{name}.png")]
