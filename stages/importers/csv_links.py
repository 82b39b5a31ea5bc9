"""`rfir import csv`: one row per link and frequency.

Columns (header required, any order): tx_x, tx_y, tx_z, rx_x, rx_y, rx_z [m], freq_hz [Hz],
power_db [dB: path gain, or received power in dBm when --tx-power-dbm is given]; optional
phase_rad [rad], aspect_deg [deg], range_m [m], rcs_dbsm [dBsm], tx_id, rx_id, split (train/test/0/1).
Rows sharing (tx, rx, aspect, range) form one link; every link needs every frequency.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rfir_cli.artifacts import write_artifact
from rfir_cli.errors import InputFileError
from rfir_cli.provenance import Provenance

from .rows import RowProblems, check_metres

REQUIRED = ("tx_x", "tx_y", "tx_z", "rx_x", "rx_y", "rx_z", "freq_hz", "power_db")
OPTIONAL_FLOATS = ("phase_rad", "aspect_deg", "range_m", "rcs_dbsm")
OPTIONAL_INTS = ("tx_id", "rx_id")
SPLIT_WORDS = {"train": 0, "0": 0, "test": 1, "1": 1, "": -1, "-1": -1}


@dataclass
class CsvImportResult:
    """What an import wrote: the artifact path, links L, frequencies F and the task."""

    path: Path
    links: int
    freqs: int
    task: str


def _number(text: str, line: int, column: str, problems: RowProblems) -> float:
    try:
        value = float(text)
    except ValueError:
        problems.add(f"line {line}, column {column}: {text!r} is not a number")
        return math.nan
    if not math.isfinite(value):
        problems.add(f"line {line}, column {column}: {text} is not a finite number")
    return value


def read_links_csv(path: str | Path, position_scale: float = 1.0) -> dict:
    """Parse and validate a links CSV. Returns the `measurements` datasets (and `task`).

    Raises InputFileError naming the file and every bad row (up to a few) if anything is wrong.
    """
    path = Path(path)
    problems = RowProblems(str(path))
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            reader = csv.DictReader(handle)
            header = [h.strip() for h in (reader.fieldnames or [])]
            rows = list(reader)
    except FileNotFoundError:
        raise InputFileError("file not found", path=path) from None
    except (UnicodeDecodeError, csv.Error) as exc:
        raise InputFileError(f"not a readable CSV file ({exc})", path=path) from None
    missing = [c for c in REQUIRED if c not in header]
    if missing:
        raise InputFileError(f"missing required column(s): {', '.join(missing)} (header: {', '.join(header) or 'empty'})",
                             path=path)
    if not rows:
        raise InputFileError("no data rows", path=path)
    present = [c for c in OPTIONAL_FLOATS + OPTIONAL_INTS + ("split",) if c in header]
    records = []
    for index, raw in enumerate(rows):
        line = index + 2  # header is line 1
        row = {k.strip(): (v or "").strip() for k, v in raw.items() if k is not None}
        rec = {c: _number(row[c], line, c, problems) for c in REQUIRED + tuple(c for c in OPTIONAL_FLOATS if c in present)}
        for c in OPTIONAL_INTS:
            if c in present:
                value = _number(row[c], line, c, problems)
                if math.isfinite(value) and value != int(value):
                    problems.add(f"line {line}, column {c}: {row[c]!r} is not an integer")
                rec[c] = value
        if "split" in present:
            word = row["split"].lower()
            if word not in SPLIT_WORDS:
                problems.add(f"line {line}, column split: {row['split']!r} is not train/test/0/1")
            rec["split"] = SPLIT_WORDS.get(word, -1)
        if math.isfinite(rec["freq_hz"]) and rec["freq_hz"] < 1e6:
            problems.add(f"line {line}, column freq_hz: {rec['freq_hz']:g} Hz is below 1 MHz: give Hz, not GHz or MHz")
        records.append((line, rec))
    problems.raise_if_any()
    return _assemble(path, records, present, problems, position_scale)


def _link_key(rec: dict) -> tuple:
    """Rows with the same positions, aspect and range belong to one link."""
    return tuple(rec[c] for c in REQUIRED[:6]) + tuple(rec.get(c, 0.0) for c in ("aspect_deg", "range_m"))


def _assemble(path: Path, records: list, present: list, problems: RowProblems, scale: float) -> dict:
    """Group rows into links x frequencies, refusing conflicting duplicates and missing cells."""
    freqs = sorted({rec["freq_hz"] for _, rec in records})
    freq_index = {f: i for i, f in enumerate(freqs)}
    link_keys: dict[tuple, int] = {}
    cells: dict[tuple, tuple] = {}
    value_cols = ["power_db"] + [c for c in ("phase_rad", "rcs_dbsm") if c in present]
    for line, rec in records:
        link = link_keys.setdefault(_link_key(rec), len(link_keys))
        cell = (link, freq_index[rec["freq_hz"]])
        values = tuple(rec[c] for c in value_cols)
        if cell in cells:
            first_line, first_values = cells[cell]
            if first_values != values:
                problems.add(f"lines {first_line} and {line}: the same link and frequency with different values "
                             f"({', '.join(f'{c}={a:g} vs {b:g}' for c, a, b in zip(value_cols, first_values, values) if a != b)})")
            continue
        cells[cell] = (line, values)
    n_links, n_freqs = len(link_keys), len(freqs)
    if len(cells) != n_links * n_freqs:
        have: dict[int, tuple[int, set]] = {}
        for (link, f), (line, _) in cells.items():
            have.setdefault(link, (line, set()))[1].add(f)
        incomplete = [(line, got) for line, got in have.values() if len(got) != n_freqs]
        for line, got in incomplete:
            lacking = [f"{freqs[i]:g}" for i in range(n_freqs) if i not in got]
            problems.add(f"link first seen on line {line} lacks frequency {', '.join(lacking[:3])} Hz "
                         f"(every link needs every frequency)")
    first_row = {}
    for _, rec in records:
        first_row.setdefault(link_keys[_link_key(rec)], rec)
    ordered = [first_row[i] for i in range(n_links)]
    tx = np.array([[r["tx_x"], r["tx_y"], r["tx_z"]] for r in ordered]) * scale
    rx = np.array([[r["rx_x"], r["rx_y"], r["rx_z"]] for r in ordered]) * scale
    check_metres(np.concatenate([tx, rx]), "positions", problems)
    problems.raise_if_any()
    grid = {c: np.full((n_links, n_freqs), np.nan) for c in value_cols}
    for (link, f), (_, values) in cells.items():
        for c, v in zip(value_cols, values):
            grid[c][link, f] = v
    data = {"tx_pos": tx, "rx_pos": rx, "freq_hz": np.array(freqs, dtype=np.float64), "path_gain_db": grid["power_db"]}
    if "phase_rad" in grid:
        amplitude = 10.0 ** (grid["power_db"] / 20.0)
        data["channel"] = amplitude * np.exp(1j * grid["phase_rad"])
    if "rcs_dbsm" in grid:
        data["rcs_dbsm"] = grid["rcs_dbsm"]
    if "aspect_deg" in present:
        data["aspect_rad"] = np.deg2rad([r["aspect_deg"] for r in ordered])
    if "range_m" in present:
        data["range_m"] = np.array([r["range_m"] for r in ordered]) * scale
    for c in OPTIONAL_INTS:
        if c in present:
            data[c] = np.array([int(r[c]) for r in ordered], dtype=np.int64)
    if "split" in present:
        data["split"] = np.array([r["split"] for r in ordered], dtype=np.int64)
    task = "rcs" if ("rcs_dbsm" in present or "aspect_deg" in present) else "rssi"
    if task == "rcs" and n_freqs > 1:
        task = "wideband"
    return {"data": data, "task": task}


def import_csv(path: str | Path, out: str | Path, *, scene: str = "imported", tx_power_dbm: float | None = None,
               position_scale: float = 1.0, config_toml: str = "") -> CsvImportResult:
    """Validate a links CSV and write a `measurements` artifact (nothing is written on any error).

    tx_power_dbm: when given, power_db is read as received power in dBm and converted to path gain.
    position_scale: multiply coordinates and ranges by this (0.001 for millimetres).
    """
    parsed = read_links_csv(path, position_scale)
    data = parsed["data"]
    if tx_power_dbm is not None:
        data["path_gain_db"] = data["path_gain_db"] - tx_power_dbm
        if "channel" in data:
            data["channel"] = data["channel"] * 10.0 ** (-tx_power_dbm / 20.0)
    prov = Provenance(stage="import", config_toml=config_toml,
                      extra={"format": "csv", "tx_power_dbm": tx_power_dbm, "position_scale": position_scale})
    prov.add_input(path)
    attrs = {"task": parsed["task"], "scene": scene}
    if tx_power_dbm is not None:
        attrs["tx_power_dbm"] = float(tx_power_dbm)
    target = write_artifact(out, "measurements", data, attrs=attrs, provenance=prov)
    return CsvImportResult(target, data["tx_pos"].shape[0], data["freq_hz"].size, parsed["task"])
