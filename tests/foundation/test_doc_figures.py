"""A figure in dB that a doc states lives in a generated table; other pages link to the table.

A doc is README.md or a page under docs/ (generated pages aside: docs/results.md, docs/reference/, and the
schema block of docs/artifacts.md). A figure is a number with a decimal point followed by "dB" (not dBm,
dBi or dBsm: levels, not errors), with the numbers listed before it ("0.35 / 0.30 dB", "1.3-1.7 dB",
"0.44, 0.80 and 0.40 dB"), or a number after "MAE" ("MAE 3.2", "MAE of 0.29"). Integers ("within 3 dB",
"-8 dB on links crossing a box") are thresholds, settings and rules of thumb, not measured figures.

A figure passes when it is, at the decimals it is written with, a number of a generated table
(results/reproduce/*.md, *.csv, *.json, the diagnose set's table, docs/results.md), the value of a dB
setting in configs/*.toml (a key whose name holds "db"), or a closed form of ALLOWED below. Inline code
(`--noise-db 0.5`) is not prose and is skipped.
"""
from __future__ import annotations

import csv
import json
import math
import re
import tomllib
from pathlib import Path

from rfir_core.schema_doc import BEGIN as SCHEMA_BEGIN, END as SCHEMA_END

ROOT = Path(__file__).resolve().parents[2]

GENERATED_PAGES = {"docs/results.md"}
GENERATED_FOLDERS = ("docs/reference/",)
SCHEMA_BLOCK = (SCHEMA_BEGIN, SCHEMA_END)    # docs/artifacts.md's block that rfir_core.schema_doc writes

# Closed forms and fixed physical facts a doc may state without a table, each with why it holds.
ALLOWED: dict[str, str] = {
    "3.01": "10 log10(2): twice the power",
    "6.02": "20 log10(2): twice the field amplitude",
    "4.34": "10 / ln(10): dB per neper of power (the slope of dB against ln)",
    "8.69": "20 / ln(10): dB per neper of amplitude",
}

_NUM = r"-?\d+(?:\.\d+)?"
# a run of numbers joined by "/", "-", "to", ",", "and", "or", "against" and ending in dB (not dBm, dBsm, dBi)
FIGURE_RUN = re.compile(rf"((?:{_NUM}\s*(?:/|-|–|to|,|and|or|against|->|→)\s*)*{_NUM})\s*dB(?![a-zA-Z])")
AFTER_MAE = re.compile(rf"\bMAE\s+(?:of\s+|is\s+|=\s*|:\s*)?({_NUM})")
INLINE_CODE = re.compile(r"`[^`]*`")
NUMBER = re.compile(_NUM)


def doc_files(root: Path = ROOT) -> list[Path]:
    pages = sorted((root / "docs").rglob("*.md")) + [root / "README.md"]
    out = []
    for p in pages:
        rel = p.relative_to(root).as_posix()
        if p.exists() and rel not in GENERATED_PAGES and not rel.startswith(GENERATED_FOLDERS):
            out.append(p)
    return out


def prose_lines(text: str) -> list[tuple[int, str]]:
    """(line number, line) of a page, inline code removed, a generated schema block left out."""
    out, skipping = [], False
    for n, line in enumerate(text.splitlines(), 1):
        if line.startswith(SCHEMA_BLOCK[0]):
            skipping = True
        elif line.startswith(SCHEMA_BLOCK[1]):
            skipping = False
        elif not skipping:
            out.append((n, INLINE_CODE.sub(" ", line)))
    return out


def figures(line: str) -> list[str]:
    """The figures a line of prose states (as written, sign dropped; integers left out)."""
    found = []
    for run in FIGURE_RUN.findall(line):
        found += NUMBER.findall(run)
    found += AFTER_MAE.findall(line)
    out = []
    for f in found:
        f = f.lstrip("-")
        if "." in f and f not in out:
            out.append(f)
    return out


def _db_numbers_in_json(node, out: set[float], in_db: bool = False) -> None:
    """Numbers under a key named in dB (mae_db, median_abs_db; not levels in dBsm), absolute; a list longer than
    16 is a curve, not a figure."""
    if isinstance(node, dict):
        for key, v in node.items():
            _db_numbers_in_json(v, out, in_db or DB_KEY.search(str(key)) is not None)
    elif isinstance(node, list) and len(node) <= 16:
        for v in node:
            _db_numbers_in_json(v, out, in_db)
    elif in_db and isinstance(node, (int, float)) and not isinstance(node, bool) and math.isfinite(node):
        out.add(abs(float(node)))


DB_CAPTION = re.compile(r"\bdB\b")
DB_KEY = re.compile(r"(?:^|_)db(?:$|_)", re.IGNORECASE)


def _db_numbers_in_markdown(text: str) -> set[float]:
    """The dB figures of a generated page: the cells of a table whose caption says dB ("MAE in dB ..."),
    and the figures its lines state (notes, labels such as "unedited 0.29 dB")."""
    values, db_table = set(), False
    for line in text.splitlines():
        values.update(abs(float(f)) for f in figures(line))
        if line.startswith("|"):
            if db_table:
                for cell in line.strip().strip("|").split("|")[1:]:
                    values.update(abs(float(x)) for x in NUMBER.findall(cell))
        elif line.strip():
            db_table = bool(DB_CAPTION.search(line))
    return values


def table_values(root: Path = ROOT) -> set[float]:
    """Every dB figure of the generated tables (absolute values): the MAE column of the CSVs, the dB tables
    and stated figures of the Markdown, the dB-named values of the JSON."""
    values: set[float] = set()
    results = root / "results" / "reproduce"
    for path in [*results.glob("*.md"), *(results / "diagnose").glob("*.md"), root / "docs" / "results.md"]:
        if path.exists():
            values |= _db_numbers_in_markdown(path.read_text(encoding="utf-8"))
    for path in results.glob("*.csv"):
        with path.open(encoding="utf-8") as fh:
            values.update(abs(float(r["mae_db"])) for r in csv.DictReader(fh) if r.get("mae_db"))
    for path in [*results.glob("*.json"), *(results / "diagnose").glob("*.json"),
                 *(results / "fullwave").glob("*.json")]:
        _db_numbers_in_json(json.loads(path.read_text(encoding="utf-8")), values)
    return values


def config_db_values(root: Path = ROOT) -> set[float]:
    """Values of the dB settings of configs/*.toml (keys whose name holds "db"), absolute."""
    values: set[float] = set()

    def walk(node) -> None:
        for key, v in node.items():
            if isinstance(v, dict):
                walk(v)
            elif "db" in key.lower():
                for x in v if isinstance(v, list) else [v]:
                    if isinstance(x, (int, float)) and not isinstance(x, bool):
                        values.add(abs(float(x)))

    for path in sorted((root / "configs").rglob("*.toml")):
        walk(tomllib.loads(path.read_text(encoding="utf-8")))
    return values


def matches(figure: str, values: set[float]) -> bool:
    """Whether some value, written with the figure's decimals, reads as the figure."""
    decimals = len(figure.split(".")[1]) if "." in figure else 0
    target = float(figure)
    tol = 0.5 * 10 ** -decimals + 1e-9
    return any(abs(v - target) <= tol for v in values)


def drifting_figures(root: Path = ROOT) -> list[str]:
    """'file:line: figure' for every figure no table, dB setting or closed form holds."""
    tables, settings = table_values(root), config_db_values(root)
    bad = []
    for path in doc_files(root):
        rel = path.relative_to(root).as_posix()
        for n, line in prose_lines(path.read_text(encoding="utf-8")):
            for f in figures(line):
                if f in ALLOWED or matches(f, tables) or any(abs(float(f) - v) < 1e-9 for v in settings):
                    continue
                bad.append(f"{rel}:{n}: {f} dB")
    return bad


def test_every_figure_in_db_a_doc_states_is_in_a_generated_table():
    bad = drifting_figures()
    assert not bad, ("figures in dB that no generated table holds (link to docs/results.md#<target> instead of "
                     "quoting, or add a closed form to ALLOWED with its reason):\n" + "\n".join(bad))


def test_the_figures_found_are_those_a_reader_sees():
    assert figures("rfir scores 2.90 dB, against 3.34 / 3.20 dB and 1.3-1.7 dB") == ["2.90", "3.34", "3.20", "1.3", "1.7"]
    assert figures("held-out MAE 3.2 on the lab; the MAE of 0.29 and 0.44, 0.80 and 0.40 dB") == [
        "0.29", "0.44", "0.80", "0.40", "3.2"]
    assert figures("a -80 dBm floor, 8.14 dBsm at broadside, 2.15 dBi gain, within 3 dB, 12.5 % of links") == []
    assert figures("2.88 -> 0.43 dB, 24 degrees, MAE 3 dB") == ["2.88", "0.43"]
    assert prose_lines(f"run `--noise-db 0.5` with 0.25 dB\n{SCHEMA_BEGIN}\n1.5 dB\n{SCHEMA_END}\nend") == [
        (1, "run   with 0.25 dB"), (5, "end")]


def test_a_figure_matches_at_its_own_decimals_only():
    values = {2.904, 0.35, 12.36}
    assert matches("2.90", values) and matches("2.9", values) and matches("12.4", values)
    assert not matches("2.91", values) and not matches("0.36", values) and not matches("12.3", values)


def test_a_drifted_figure_is_reported_with_its_file_and_line(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "results" / "reproduce").mkdir(parents=True)
    (tmp_path / "configs").mkdir()
    (tmp_path / "results" / "reproduce" / "rssi.md").write_text(
        "MAE in dB:\n\n| row | rfir | log-distance |\n|---|---|---|\n| classroom | **0.35** | 3.29 |\n\n"
        "Wall time (minutes):\n\n| row | rfir |\n|---|---|\n| classroom | 0.36 |\n")
    (tmp_path / "configs" / "predict.toml").write_text("[predict.rcs.flashes]\ntolerance_db = 3.5\n")
    (tmp_path / "docs" / "rssi.md").write_text("# RSSI\nrfir scores 0.35 dB (flashes within 3.5 dB).\n\n"
                                               "Copied by hand: 0.36 dB, twice the power is 3.01 dB.\n")
    (tmp_path / "docs" / "results.md").write_text("9.99 dB (a generated page is not checked)\n")
    (tmp_path / "README.md").write_text("The lab: MAE 2.9.\n")
    assert drifting_figures(tmp_path) == ["docs/rssi.md:4: 0.36 dB", "README.md:1: 2.9 dB"]
