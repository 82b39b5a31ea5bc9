"""`rfir import nerf2-ble DIR`: NeRF2's BLE layout, the de-facto format of neural radio fields.

DIR holds gateway_position.yml (gateway name -> [x, y, z] in metres), tx_pos.csv (one header line,
then x, y, z per transmitter) and gateway_rssi.csv (one header line naming the gateways, then one
row per transmitter, RSSI in dBm, -100 meaning not received). Optional train_index.txt /
test_index.txt list transmitter row indices. Gateways are receivers; a link is (tx, gateway).
"""
from __future__ import annotations

import csv
import io
from pathlib import Path

import numpy as np
import yaml

from rfir_core.artifacts import write_artifact
from rfir_core.errors import InputFileError
from rfir_core.provenance import Provenance

from .csv_links import CsvImportResult
from .rows import RowProblems, check_metres
from .units import check_position_scale

MISSING_DBM = -100.0


def _read_table(path: Path, columns: int | None, problems: RowProblems) -> tuple[list[str], np.ndarray]:
    """A numeric CSV with one header line -> (header, values [rows, cols]); bad cells are recorded."""
    try:
        rows = list(csv.reader(io.StringIO(_text(path), newline="")))
    except csv.Error as exc:
        raise InputFileError(f"not a readable CSV file ({exc})", path=path) from None
    if len(rows) < 2:
        raise InputFileError("needs a header line and at least one data row", path=path)
    header, body = [h.strip() for h in rows[0]], rows[1:]
    width = columns or len(header)
    values = np.full((len(body), width), np.nan)
    for index, row in enumerate(body):
        line = index + 2
        if len(row) != width:
            problems.add(f"line {line}: {len(row)} values, expected {width}")
            continue
        for col, text in enumerate(row):
            column = header[col] if col < len(header) else str(col + 1)
            try:
                values[index, col] = float(text)
            except ValueError:
                problems.add(f"line {line}, column {column}: {text!r} is not a number")
                continue
            if not np.isfinite(values[index, col]):
                problems.add(f"line {line}, column {column}: {text} is not a finite number")
    return header, values


def _text(path: Path) -> str:
    """A file of the layout as text; a one-line InputFileError when missing, not UTF-8 or binary."""
    if not path.is_file():
        raise InputFileError("file not found (NeRF2 BLE layout needs it)", path=path)
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputFileError(f"not a UTF-8 text file (byte {exc.start}: {exc.reason})", path=path) from None
    if "\x00" in text:
        raise InputFileError("not a text file (holds NUL bytes)", path=path)
    return text


def _read_gateways(path: Path) -> dict[str, np.ndarray]:
    text = _text(path)
    try:
        content = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise InputFileError(f"not valid YAML: {str(exc).splitlines()[0]}", path=path) from None
    if not isinstance(content, dict) or not content:
        raise InputFileError("expected a mapping of gateway name -> [x, y, z]", path=path)
    gateways = {}
    for name, pos in content.items():
        if isinstance(pos, dict) and "position" in pos:
            pos = pos["position"]
        try:
            array = np.asarray(pos, dtype=float) if isinstance(pos, (list, tuple)) else None
        except (TypeError, ValueError):
            array = None
        if array is None or array.shape != (3,) or not np.all(np.isfinite(array)):
            raise InputFileError(f"gateway {name!r}: position must be three finite numbers, got {pos!r}", path=path)
        gateways[str(name)] = array
    return gateways


def import_nerf2_ble(folder: str | Path, out: str | Path, *, freq_hz: float = 2.4e9, tx_power_dbm: float = 0.0,
                     position_scale: float = 1.0, scene: str = "nerf2-ble", config_toml: str = "") -> CsvImportResult:
    """Convert a NeRF2 BLE folder into a `measurements` artifact (links with RSSI -100 are dropped).

    path_gain_db = RSSI [dBm] - tx_power_dbm (the beacons' transmit power is not in the data set).
    """
    folder = Path(folder)
    position_scale = check_position_scale(position_scale)
    if not folder.is_dir():
        raise InputFileError("not a folder (expected NeRF2's BLE layout)", path=folder)
    gateways = _read_gateways(folder / "gateway_position.yml")
    problems_tx = RowProblems(str(folder / "tx_pos.csv"))
    _, tx = _read_table(folder / "tx_pos.csv", 3, problems_tx)
    problems_tx.raise_if_any()
    problems_rssi = RowProblems(str(folder / "gateway_rssi.csv"))
    names, rssi = _read_table(folder / "gateway_rssi.csv", None, problems_rssi)
    unknown = [n for n in names if n not in gateways]
    if unknown:
        problems_rssi.add(f"header names gateway(s) {', '.join(unknown[:3])} missing from gateway_position.yml")
    if rssi.shape[0] != tx.shape[0]:
        problems_rssi.add(f"{rssi.shape[0]} rows but tx_pos.csv has {tx.shape[0]} transmitters")
    problems_rssi.raise_if_any()
    gw_pos = np.stack([gateways[n] for n in names]) * position_scale
    tx = tx * position_scale
    scale_check = RowProblems(str(folder))
    check_metres(np.concatenate([tx, gw_pos]), "positions", scale_check)
    scale_check.raise_if_any()
    split_of_tx = np.full(tx.shape[0], -1, dtype=np.int64)
    for name, value in (("train_index.txt", 0), ("test_index.txt", 1)):
        if (folder / name).exists():
            words = _text(folder / name).split()
            if not all(w.lstrip("-").isdigit() and len(w) < 18 for w in words):
                raise InputFileError("expected whole numbers (transmitter row indices)", path=folder / name)
            index = np.array([int(w) for w in words], dtype=np.int64)
            if index.size and (index.min() < 0 or index.max() >= tx.shape[0]):
                raise InputFileError(f"indices outside 0..{tx.shape[0] - 1}", path=folder / name)
            split_of_tx[index] = value
    t_idx, g_idx = np.nonzero(rssi > MISSING_DBM)
    if t_idx.size == 0:
        raise InputFileError(f"every RSSI is {MISSING_DBM:g} (nothing received)", path=folder / "gateway_rssi.csv")
    data = {
        "tx_pos": tx[t_idx], "rx_pos": gw_pos[g_idx], "freq_hz": np.array([float(freq_hz)]),
        "path_gain_db": (rssi[t_idx, g_idx] - tx_power_dbm)[:, None],
        "tx_id": t_idx.astype(np.int64), "rx_id": g_idx.astype(np.int64), "split": split_of_tx[t_idx],
    }
    prov = Provenance(stage="import", config_toml=config_toml,
                      extra={"format": "nerf2-ble", "gateways": names, "dropped_links": int((rssi <= MISSING_DBM).sum())})
    for name in ("gateway_position.yml", "tx_pos.csv", "gateway_rssi.csv"):
        prov.add_input(folder / name)
    target = write_artifact(out, "measurements", data, attrs={"task": "rssi", "scene": scene, "power": "rssi",
                                                                  "tx_power_dbm": float(tx_power_dbm)},
                            provenance=prov)
    return CsvImportResult(target, int(t_idx.size), 1, "rssi")
