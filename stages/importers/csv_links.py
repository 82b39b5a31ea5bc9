"""`rfir import csv`: one row per link and frequency.

Columns (header required, any order): tx_x, tx_y, tx_z, rx_x, rx_y, rx_z [m], freq_hz [Hz],
power_db [dB; its meaning is the set-up's `power`: path gain, RCS in dBsm or RSSI in dBm];
optional phase_rad [rad], aspect_deg [deg], range_m [m], rcs_dbsm [dBsm], tx_id, rx_id, split
(train/test/0/1), and each side's antenna axis per link (AXIS_COLUMNS: tx_ax, tx_ay, tx_az, or
HEADING_COLUMNS: tx_heading_deg; rx_ likewise; stored as tx_axis / rx_axis). Rows sharing (tx, rx,
aspect, range, axes) form one link; every link needs every
frequency. Repeated rows of one link and frequency with different values are refused unless an
average is asked for (AVERAGES: "mean-db" averages the dB values, "mean-power" the linear powers;
the rows per link and their spread are stored as sample_count and sample_std_db). `# key = value`
lines before the header, a sidecar TOML and import flags state the measurement set-up
(meas_setup.py); units.py reads other units and column names, split.py writes a split, sanity.py
refuses values whose units look wrong.
"""
from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rfir_core.artifacts import write_artifact
from rfir_core.errors import InputFileError
from rfir_core.provenance import Provenance

from rfir_core.physics.closed_forms import rcs_from_path_gain

from rfir_core.errors import ConfigError

from .meas_setup import MeasurementSetup, boresight_gain, header_options, resolve_setup, split_header
from .rows import RowProblems, check_metres
from .sanity import check_units
from .split import HELP as SPLIT_HELP
from .split import assign_split, parse_split
from .tasks import check_turntable, detect_task
from .units import RECEIVED_POWER_UNITS, Units, parse_columns, resolve_units

REQUIRED = ("tx_x", "tx_y", "tx_z", "rx_x", "rx_y", "rx_z", "freq_hz", "power_db")
OPTIONAL_FLOATS = ("phase_rad", "aspect_deg", "range_m", "rcs_dbsm")
ABSENT_OK = ("phase_rad",)             # a cell of these may be empty: not measured on that row
ABSENT_WORDS = ("", "nan", "na", "n/a")
OPTIONAL_INTS = ("tx_id", "rx_id")
SAMPLE_COLUMNS = ("sample_count", "sample_std_db")   # a file of links averaged already: samples per link, spread [dB]
SPLIT_WORDS = {"train": 0, "0": 0, "test": 1, "1": 1, "": -1, "-1": -1}
# an antenna's axis per link (a dipole's axis, a horn's or table's boresight) in the room frame, normalised: three
# components, or a heading h [deg] about +z from +x toward +y, the horizontal axis (cos h, sin h, 0)
AXIS_COLUMNS = {"tx": ("tx_ax", "tx_ay", "tx_az"), "rx": ("rx_ax", "rx_ay", "rx_az")}
HEADING_COLUMNS = {"tx": "tx_heading_deg", "rx": "rx_heading_deg"}
COLUMNS = (REQUIRED + OPTIONAL_FLOATS + OPTIONAL_INTS + SAMPLE_COLUMNS + ("split",) + AXIS_COLUMNS["tx"] + AXIS_COLUMNS["rx"]
           + tuple(HEADING_COLUMNS.values()))
AVERAGES = ("mean-db", "mean-power")
AVERAGE_HINT = "repeated samples of one link: pass --average mean-db or --average mean-power to average them"


@dataclass
class CsvImportResult:
    """What an import wrote: the artifact path, links L, frequencies F, the task and lines to print."""

    path: Path
    links: int
    freqs: int
    task: str
    notes: list = field(default_factory=list)


def _number(text: str, line: int, column: str, problems: RowProblems) -> float:
    try:
        value = float(text)
    except ValueError:
        problems.add(f"line {line}, column {column}: {text!r} is not a number")
        return math.nan
    if not math.isfinite(value):
        problems.add(f"line {line}, column {column}: {text} is not a finite number")
    return value


def read_links_csv(path: str | Path, position_scale: float = 1.0, *, units: Units | None = None,
                   columns: dict | None = None, average: str | None = None) -> dict:
    """Parse and validate a links CSV. Returns the `measurements` datasets, the header's set-up
    options (`options`: key -> text), the present optional columns and the rows read (`rows`).

    position_scale [m per file unit] (units.position_scale when units are given); units: the power
    and frequency units of the file (units.py; default dB and Hz); columns: {rfir column: the
    file's header} for columns named differently; average: None (refuse repeated rows with
    different values) or one of AVERAGES.
    Raises InputFileError naming the file and every bad row (up to a few) if anything is wrong.
    """
    path = Path(path)
    units = units or Units(position_scale=position_scale)
    columns = dict(columns or {})
    if average is not None and average not in AVERAGES:
        raise ConfigError(f"--average {average!r}: expected {' or '.join(AVERAGES)}")
    problems = RowProblems(str(path))
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except FileNotFoundError:
        raise InputFileError("file not found", path=path) from None
    except IsADirectoryError:
        raise InputFileError("is a folder, expected a CSV file", path=path) from None
    except UnicodeDecodeError as exc:
        raise InputFileError(f"not a UTF-8 text file (byte {exc.start}: {exc.reason})", path=path) from None
    if "\x00" in text:
        raise InputFileError("not a text file (holds NUL bytes)", path=path)
    comments, body = split_header(text)
    options = header_options(comments, str(path))
    offset = len(text.splitlines()) - len(body.splitlines())   # lines before the column header
    try:
        reader = csv.DictReader(io.StringIO(body, newline=""))
        header = [h.strip() for h in (reader.fieldnames or [])]
        rows = list(reader)
    except csv.Error as exc:
        raise InputFileError(f"not a readable CSV file ({exc})", path=path) from None
    absent = [f"--column {name}={source}" for name, source in columns.items() if source not in header]
    if absent:
        raise InputFileError(f"{', '.join(absent)}: no such column in the file (header: {', '.join(header) or 'empty'})",
                             path=path)
    named = set(header) | set(columns)
    missing = [c for c in REQUIRED if c not in named]
    if missing:
        raise InputFileError(f"missing required column(s): {', '.join(missing)} (header: {', '.join(header) or 'empty'}; "
                             f"a column named otherwise: --column {missing[0]}=NAME)", path=path)
    if not rows:
        raise InputFileError("no data rows", path=path)
    present = [c for c in OPTIONAL_FLOATS + OPTIONAL_INTS + SAMPLE_COLUMNS + ("split",) if c in named]
    if average is not None and any(c in present for c in SAMPLE_COLUMNS):
        raise ConfigError("--average: the file's sample_count / sample_std_db columns say its links are averaged "
                          "already; drop --average")
    ignored = [h for h in header if h and h not in COLUMNS and h not in columns.values()]
    axis_sources = _axis_sources(named, path)
    id_names = {c: _id_numbers([(r.get(columns.get(c, c)) or "").strip() for r in rows]) for c in OPTIONAL_INTS
                if c in named}
    records = []
    for index, raw in enumerate(rows):
        line = offset + index + 2  # the column header is line offset + 1
        if None in raw or any(v is None for v in raw.values()):
            problems.add(f"line {line}: {len(header) + len(raw.get(None) or [])} values for {len(header)} columns"
                         if None in raw else f"line {line}: fewer values than the {len(header)} columns")
            continue
        row = {k.strip(): (v or "").strip() for k, v in raw.items() if k is not None}
        row.update({name: row[source] for name, source in columns.items()})
        rec = {c: _number(row[c], line, c, problems) for c in REQUIRED + tuple(c for c in OPTIONAL_FLOATS if c in present)
               if not (c in ABSENT_OK and row[c].lower() in ABSENT_WORDS)}
        rec.update({c: math.nan for c in ABSENT_OK if c in present and c not in rec})   # absent, never 0.0
        for c in SAMPLE_COLUMNS:
            if c in present:
                value = _number(row[c], line, c, problems)
                if math.isfinite(value) and (value < 0 or (c == "sample_count" and (value < 1 or value != int(value)))):
                    problems.add(f"line {line}, column {c}: {row[c]!r} is not " + (
                        "a whole number of samples (1 or more)" if c == "sample_count" else "a spread of 0 dB or more"))
                rec[c] = value
        for c in OPTIONAL_INTS:
            if c in present and id_names.get(c):
                rec[c] = float(id_names[c][row[c]])
            elif c in present:
                value = _number(row[c], line, c, problems)
                if math.isfinite(value) and (value != int(value) or abs(value) >= 2**62):
                    problems.add(f"line {line}, column {c}: {row[c]!r} is not an integer")
                    value = math.nan
                rec[c] = value
        for side, source in axis_sources.items():
            rec[f"{side}_axis"] = _axis(row, source, line, problems)
        if "split" in present:
            word = row["split"].lower()
            if word not in SPLIT_WORDS:
                problems.add(f"line {line}, column split: {row['split']!r} is not train/test/0/1")
            rec["split"] = SPLIT_WORDS.get(word, -1)
        if units.power != "dB" and math.isfinite(rec["power_db"]):
            value = units.to_dbm(rec["power_db"])
            if not math.isfinite(value):
                problems.add(f"line {line}, column power_db: {row['power_db']!r} is not a positive power in {units.power} "
                             "(--power-unit)")
            rec["power_db"] = value
        rec["freq_hz"] = rec["freq_hz"] * units.freq_scale
        if math.isfinite(rec["freq_hz"]) and rec["freq_hz"] < 1e6:
            problems.add(f"line {line}, column freq_hz: {rec['freq_hz']:g} Hz is below 1 MHz: give Hz, not GHz or MHz "
                         "(or pass --freq-unit GHz or MHz)")
        rec["_line"] = line
        records.append((line, rec))
    problems.raise_if_any()
    out = _assemble(path, records, present, problems, units.position_scale, average)
    out.update(options=options, present=present, rows=len(records), ignored=ignored,
               id_names={c: m for c, m in id_names.items() if m}, axes=axis_sources)
    return out


def _axis_sources(named: set, path: Path) -> dict:
    """{side: its axis columns (AXIS_COLUMNS) or heading column (HEADING_COLUMNS)} of the sides the file gives an
    axis per link; an InputFileError naming the file for a side given only part of the three components, or both."""
    out = {}
    for side, trio in AXIS_COLUMNS.items():
        have = [c for c in trio if c in named]
        heading = HEADING_COLUMNS[side] in named
        if have and len(have) < 3:
            raise InputFileError(f"column(s) {', '.join(have)} without {', '.join(c for c in trio if c not in have)}: "
                                 f"a {side} axis is the three columns {', '.join(trio)}", path=path)
        if have and heading:
            raise InputFileError(f"columns {', '.join(trio)} and {HEADING_COLUMNS[side]} both give the {side} axis: "
                                 "keep one", path=path)
        if have or heading:
            out[side] = trio if have else (HEADING_COLUMNS[side],)
    return out


def _axis(row: dict, source: tuple, line: int, problems: RowProblems) -> tuple:
    """The unit axis (3 floats) of one row from its axis columns `source` (three components, or one heading
    [deg] about +z from +x: (cos h, sin h, 0)); a problem naming the line and column for a value that is not a
    finite number or three components that are all zero."""
    values = [_number(row[c], line, c, problems) for c in source]
    if len(source) == 1:
        h = math.radians(values[0])
        values = [math.cos(h), math.sin(h), 0.0]
    norm = math.sqrt(sum(v * v for v in values))
    if norm == 0:
        problems.add(f"line {line}, columns {','.join(source)}: a zero vector has no direction")
    return tuple(v / norm for v in values) if math.isfinite(norm) and norm > 0 else (math.nan,) * 3


def _id_numbers(values: list[str]) -> dict[str, int]:
    """{name: number} for an id column that holds names ("sensor11", "p000"): numbered 0.. in sorted order;
    {} when every value is a number (read as given)."""
    try:
        for v in values:
            float(v)
        return {}
    except ValueError:
        return {name: i for i, name in enumerate(sorted(set(values)))}


def _link_key(rec: dict) -> tuple:
    """Rows with the same positions, aspect, range and antenna axes belong to one link."""
    return tuple(rec[c] for c in REQUIRED[:6]) + tuple(rec.get(c, 0.0) for c in ("aspect_deg", "range_m")) + \
        tuple(rec.get(f"{side}_axis", ()) for side in AXIS_COLUMNS)


def _mean(values: np.ndarray, column: str, average: str) -> float:
    """The average of one column's samples: phases circularly (absent ones skipped), dB values by
    `average` (mean-db: their mean; mean-power: 10 log10 of the mean linear power)."""
    if column == "phase_rad":
        finite = values[np.isfinite(values)]
        return float(np.angle(np.exp(1j * finite).mean())) if finite.size else math.nan
    if average == "mean-power":
        peak = float(values.max())
        return peak + 10.0 * math.log10(float(np.mean(10.0 ** ((values - peak) / 10.0))))
    return float(values.mean())


def _assemble(path: Path, records: list, present: list, problems: RowProblems, scale: float,
              average: str | None = None) -> dict:
    """Group rows into links x frequencies, refusing missing cells, and conflicting duplicates unless
    `average` is given (then repeated rows are averaged: sample_count, sample_std_db)."""
    freqs = sorted({rec["freq_hz"] for _, rec in records})
    freq_index = {f: i for i, f in enumerate(freqs)}
    link_keys: dict[tuple, int] = {}
    cells: dict[tuple, tuple] = {}
    samples: dict[tuple, list] = {}
    value_cols = ["power_db"] + [c for c in ("phase_rad", "rcs_dbsm") if c in present]
    for line, rec in records:
        link = link_keys.setdefault(_link_key(rec), len(link_keys))
        cell = (link, freq_index[rec["freq_hz"]])
        values = tuple(rec[c] for c in value_cols)
        if average is not None:
            samples.setdefault(cell, []).append(values)
        if cell in cells:
            first_line, first_values = cells[cell]
            if average is None and not all(a == b or (a != a and b != b) for a, b in zip(first_values, values)):
                problems.add(f"lines {first_line} and {line}: the same link and frequency with different values "
                             f"({', '.join(f'{c}={a:g} vs {b:g}' for c, a, b in zip(value_cols, first_values, values) if a != b)})")
                problems.hint(AVERAGE_HINT)
            continue
        cells[cell] = (line, values)
    count = std = None
    if average is not None:
        count = np.zeros((len(link_keys), len(freqs)), np.int64)
        std = np.zeros((len(link_keys), len(freqs)))
        for cell, got in samples.items():
            arr = np.asarray(got, np.float64)                         # [samples, value columns]
            cells[cell] = (cells[cell][0], tuple(_mean(arr[:, j], c, average) for j, c in enumerate(value_cols)))
            count[cell] = len(got)
            std[cell] = float(np.std(arr[:, 0], ddof=1)) if len(got) > 1 else 0.0
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
    if "phase_rad" in grid and np.all(np.isnan(grid["phase_rad"])):
        del grid["phase_rad"]                       # no phase measured at all: no channel
    if "phase_rad" in grid:   # cells without a phase stay NaN in the channel (absent, never 0.0)
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
    for side in AXIS_COLUMNS:
        if f"{side}_axis" in ordered[0]:
            data[f"{side}_axis"] = np.array([r[f"{side}_axis"] for r in ordered], dtype=np.float64)
    if "sample_count" in present:
        data["sample_count"] = np.array([int(r["sample_count"]) for r in ordered], dtype=np.int64)
    if "sample_std_db" in present:
        data["sample_std_db"] = np.repeat(np.array([r["sample_std_db"] for r in ordered])[:, None], n_freqs, axis=1)
    if average is not None:
        data["sample_count"] = count.min(axis=1)
        data["sample_std_db"] = std
    return {"data": data, "lines": np.array([r["_line"] for r in ordered], dtype=np.int64),
            "cell_counts": count}


def import_csv(path: str | Path, out: str | Path, *, scene: str = "imported", tx_power_dbm: float | None = None,
               position_scale: float = 1.0, config_toml: str = "", antenna: str | None = None,
               antenna_tx: str | None = None, antenna_rx: str | None = None, polarisation: str | None = None,
               power: str | None = None, task: str | None = None, average: str | None = None,
               split: str | None = None, seed: int = 0, power_unit: str | None = None, freq_unit: str | None = None,
               position_unit: str | None = None, columns: list[str] | None = None,
               position_scale_given: bool | None = None) -> CsvImportResult:
    """Validate a links CSV and write a `measurements` artifact (nothing is written on any error).

    The set-up (antenna..power, tx_power_dbm) comes from the flags given here, else the sidecar
    TOML, else the CSV's `# key = value` lines (meas_setup.py). power "rssi": power_db is received
    power in dBm, converted to path gain; "rcs": power_db is RCS in dBsm, converted to path gain
    by the radar equation with the antennas' boresight gains (needs range_m).
    position_scale: metres per file unit (0.001 for millimetres; must be positive), the same as
    position_unit "m", "cm" or "mm"; position_scale_given: whether the caller stated it (default:
    when it is not 1), which turns off the centimetre check.
    task: "rcs", "wideband" or "rssi" instead of the detected one (tasks.detect_task).
    average: None (repeated rows of a link with different values are refused), "mean-db" or
    "mean-power" (averaged; sample_count, sample_std_db stored).
    split: a protocol (split.py: "random:0.2", "holdout-tx:N", "block:SIZE") written as the split
    column, deterministic for `seed`; refused when the file has a split column.
    power_unit, freq_unit: the file's units (units.py); columns: "NAME=CSVNAME" texts.
    Unit sanity (sanity.py) is checked before writing. Raises InputFileError (the file) or
    ConfigError (a flag); nothing is written then.
    """
    path = Path(path)
    if position_scale_given is None:
        position_scale_given = position_scale != 1.0
    units = resolve_units(power_unit, freq_unit, position_unit, position_scale if position_scale_given else None)
    protocol = parse_split(split) if split is not None else None
    mapping = parse_columns(columns, COLUMNS)
    if units.power in RECEIVED_POWER_UNITS:
        if power is not None and str(power).strip().lower() != "rssi":
            raise ConfigError(f"--power-unit {units.power} is received power, which goes with --power rssi "
                              f"(not --power {power}) and --tx-power-dbm")
        power = "rssi"
    parsed = read_links_csv(path, units=units, columns=mapping, average=average)
    data, present = parsed["data"], parsed["present"]
    if protocol is not None and "split" in present:
        raise ConfigError(f"--split {split!r}: the file already has a split column; drop --split to keep it, or "
                          "remove the column to split anew")
    setup = resolve_setup(path, parsed["options"], {
        "antenna": antenna, "antenna_tx": antenna_tx, "antenna_rx": antenna_rx, "polarisation": polarisation,
        "power": power, "tx_power_dbm": tx_power_dbm})
    raw_db = np.array(data["path_gain_db"], copy=True)
    _apply_power(path, data, setup)
    task_name, task_rule = detect_task(present + (["rcs_dbsm"] if setup.power == "rcs" else []), data["freq_hz"],
                                       task, str(path))
    if "aspect_deg" in present:
        check_turntable(data, parsed["lines"], str(path))
    check_units(data, raw_db, setup, task_name, parsed["lines"], units.given, str(path))
    notes = [f"task {task_name}: {task_rule}", "set-up: " + setup.describe()]
    assumed = _assumptions(setup, units)
    if assumed:
        notes.append("assumed (no flag given): " + "; ".join(assumed))
    if average is not None:
        notes.append(_average_note(parsed, average))
    for c, names in parsed["id_names"].items():
        shown = ", ".join(f"{k} -> {v}" for k, v in list(names.items())[:3])
        notes.append(f"{c} holds names: numbered 0..{len(names) - 1} in sorted order ({shown}"
                     f"{', ...' if len(names) > 3 else ''})")
    if parsed["axes"]:
        notes.append(_axes_note(parsed["axes"], setup))
    if parsed["ignored"]:
        notes.append(f"columns not read by rfir: {', '.join(parsed['ignored'])} (columns: docs/artifacts.md; a "
                     "column named otherwise: --column NAME=COLUMN)")
    if protocol is not None:
        data["split"], split_note = assign_split(data, protocol, seed, task_name)
        notes.append(split_note)
    elif "split" not in present:
        notes.append(f"no split column: every link is training; pass --split {SPLIT_HELP} to hold out links")
    prov = Provenance(stage="import", config_toml=config_toml,
                      extra={"format": "csv", "position_scale": units.position_scale, "setup_origin": setup.origin,
                             "power_unit": units.power, "freq_unit": units.freq_name, "columns": mapping,
                             "average": average or "none",
                             "split": (split or "file") if "split" in data else "none",
                             "split_seed": seed if protocol is not None else None})
    prov.add_input(path)
    attrs = {"task": task_name, "scene": scene, **setup.attrs}
    target = write_artifact(out, "measurements", data, attrs=attrs, provenance=prov)
    return CsvImportResult(target, data["tx_pos"].shape[0], data["freq_hz"].size, task_name, notes=notes)


def _assumptions(setup: MeasurementSetup, units: Units) -> list[str]:
    """The import's readings that no flag, sidecar or header stated, each with the flag that changes it."""
    out = []
    if setup.origin.get("power") == "default" and "power" not in units.given:
        out.append("power_db is path gain in dB (received power in dBm: --power rssi --tx-power-dbm P; "
                   "linear: --power-unit mW|W)")
    if "position" not in units.given:
        out.append("positions in metres (--position-unit cm|mm)")
    if "freq" not in units.given:
        out.append("freq_hz in Hz (--freq-unit kHz|MHz|GHz)")
    return out


def _axes_note(sources: dict, setup: MeasurementSetup) -> str:
    """One line: each side's axis per link, the columns it came from and their convention, and whether the side's
    antenna has an axis to take it."""
    parts = []
    for side, source in sources.items():
        how = (f"{source[0]}: heading h in degrees about +z from +x toward +y, the horizontal axis (cos h, sin h, 0)"
               if len(source) == 1 else f"{','.join(source)}: a vector in the room frame (x, y, z), normalised")
        kind = str(setup.attrs.get(f"antenna_{side}", "not stated")).split(":")[0]
        use = "" if kind in ("dipole", "horn", "table") else f"; antenna_{side} is {kind}: rf-fit will not use it"
        parts.append(f"{side} from {how}{use}")
    return ("antenna axis per link (a dipole's axis, a horn's or table's boresight; replaces the set-up's): "
            + "; ".join(parts) + " (stored as " + ", ".join(f"{s}_axis" for s in sources) + ")")


def _average_note(parsed: dict, average: str) -> str:
    """One line: how many links were averaged from how many rows, and their spread."""
    data, counts = parsed["data"], parsed["cell_counts"]
    rows, links = int(parsed["rows"]), int(counts.shape[0])
    repeated = counts > 1
    head = f"average {average}: {links} links x {counts.shape[1]} frequencies averaged from {rows} rows"
    if not repeated.any():
        return head + " (no repeated samples: sample_count 1)"
    spread = data["sample_std_db"][repeated]
    return (f"{head} ({int(repeated.any(axis=1).sum())} links repeated, {int(counts.min())}-{int(counts.max())} samples "
            f"per cell; spread median {float(np.median(spread)):.2f} dB, max {float(spread.max()):.2f} dB; stored as "
            "sample_count, sample_std_db)")


def _apply_power(path: Path, data: dict, setup: MeasurementSetup) -> None:
    """Turn the power_db column (held in data["path_gain_db"]) into path gain by the set-up's `power`."""
    if setup.power == "rssi":
        p_tx = setup.attrs["tx_power_dbm"]
        data["path_gain_db"] = data["path_gain_db"] - p_tx
        if "channel" in data:
            data["channel"] = data["channel"] * 10.0 ** (-p_tx / 20.0)
    elif setup.power == "rcs":
        if "rcs_dbsm" in data:
            raise InputFileError("power = rcs reads power_db as RCS, but the file also has an rcs_dbsm column",
                                 path=path)
        if "range_m" not in data:
            raise InputFileError("power = rcs needs a range_m column (the radar equation needs the range)", path=path)
        gain = boresight_gain(setup.attrs, "antenna_tx") * boresight_gain(setup.attrs, "antenna_rx")
        # path gain [dB] = sigma [dBsm] - 10 log10 of the radar equation's sigma per unit path gain
        per_unit = rcs_from_path_gain(1.0, data["range_m"][:, None], data["freq_hz"][None], gain, 1.0)
        data["rcs_dbsm"] = data["path_gain_db"].copy()
        data["path_gain_db"] = data["rcs_dbsm"] - 10.0 * np.log10(per_unit)
        if "channel" in data:
            data["channel"] = 10.0 ** (data["path_gain_db"] / 20.0) * np.exp(1j * np.angle(data["channel"]))
