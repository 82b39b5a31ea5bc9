"""The measurement set-up of an imported file: antenna per side, polarisation, what power_db means.

Three sources, later ones winning: `# key = value` lines at the top of the CSV, a sidecar TOML
beside it (same stem: links.csv -> links.toml), import flags. Keys:

- antenna (both sides), antenna_tx, antenna_rx: "isotropic", "dipole[:AX,AY,AZ]" (axis, default
  0,0,1), "horn:HPBW_DEG" (cos^q horn of that half-power beamwidth), "table:FILE" (CSV
  theta_deg,gain_dbi, angle off boresight, read now and stored in the artifact); a horn's or a
  table's boresight after "@AX,AY,AZ" (room frame; default +z): "horn:60@1,0,0". A link's own axis
  (csv_links' axis and heading columns) replaces the one stated here.
- polarisation: "V" or "H".
- power: what the power_db column holds: "path_gain" [dB], "rcs" [dBsm, needs range_m],
  "rssi" [dBm, needs tx_power_dbm].
- tx_power_dbm: transmit power [dBm] for power = "rssi".

The result is a dict of root attributes of the measurements artifact (the schema's
measurements attributes); an antenna nobody stated is not recorded (rf-fit then says what it assumes).
"""
from __future__ import annotations

import csv
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rfir_core.errors import InputFileError
from rfir_core.physics.antennas import boresight_split, horn_boresight_gain
from rfir_core.physics.polarisation import POLARISATIONS

KEYS = ("antenna", "antenna_tx", "antenna_rx", "polarisation", "power", "tx_power_dbm")
POWERS = ("path_gain", "rcs", "rssi")


@dataclass
class MeasurementSetup:
    """Resolved set-up. attrs: root attributes to write; origin: key -> "flag"/"sidecar"/"header"/"default"."""

    attrs: dict = field(default_factory=dict)
    origin: dict = field(default_factory=dict)

    @property
    def power(self) -> str:
        return str(self.attrs["power"])

    def describe(self) -> str:
        """One line for the import report: every set-up value and where it came from."""
        parts = []
        for side in ("antenna_tx", "antenna_rx"):
            parts.append(f"{side} {self.attrs[side]} ({self.origin[side]})" if side in self.attrs
                         else f"{side} not stated (rf-fit will assume isotropic)")
        if "polarisation" in self.attrs:
            parts.append(f"polarisation {self.attrs['polarisation']} ({self.origin['polarisation']})")
        power = f"power_db is {self.power} ({self.origin['power']})"
        if "tx_power_dbm" in self.attrs:
            power += f", tx power {self.attrs['tx_power_dbm']:g} dBm"
        return "; ".join(parts + [power])


def split_header(text: str) -> tuple[list[tuple[int, str]], str]:
    """Leading '#' lines [(line number, text after '#')] and the rest of a CSV text."""
    lines = text.splitlines(keepends=True)
    options = []
    i = 0
    while i < len(lines) and (lines[i].lstrip().startswith("#") or not lines[i].strip()):
        if lines[i].lstrip().startswith("#"):
            options.append((i + 1, lines[i].lstrip()[1:].strip()))
        i += 1
    return options, "".join(lines[i:])


def header_options(options: list[tuple[int, str]], where: str) -> dict:
    """`key = value` comment lines -> {key: value}; other comments (no '=') are ignored."""
    out = {}
    for line, text in options:
        if "=" not in text:
            continue
        key, _, value = (s.strip() for s in text.partition("="))
        if key not in KEYS:
            raise InputFileError(f"line {line}: unknown option {key!r} (known: {', '.join(KEYS)})", path=where)
        out[key] = value.strip("'\"")
    return out


def sidecar_options(csv_path: Path) -> tuple[dict, Path | None]:
    """The sidecar TOML beside the CSV (same stem, .toml) -> ({key: value}, its path), or ({}, None)."""
    path = csv_path.with_suffix(".toml")
    if path == csv_path or not path.is_file():
        return {}, None
    try:
        content = tomllib.loads(path.read_bytes().decode("utf-8"))
    except (UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputFileError(f"not a readable TOML file ({str(exc).splitlines()[0]})", path=path) from None
    unknown = [k for k in content if k not in KEYS]
    if unknown:
        raise InputFileError(f"unknown key(s) {', '.join(unknown)} (known: {', '.join(KEYS)})", path=path)
    return {k: v if isinstance(v, (int, float)) and not isinstance(v, bool) else str(v) for k, v in content.items()}, path


def _number(text, what: str, where: str) -> float:
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise InputFileError(f"{what}: {text!r} is not a number", path=where) from None
    if not math.isfinite(value):
        raise InputFileError(f"{what}: {text!r} is not a finite number", path=where)
    return value


def antenna_attrs(side: str, text: str, where: str, base_dir: Path) -> dict:
    """Attributes of one side from an antenna text (see the module docstring); tables are read here."""
    base, at, boresight = str(text).strip().rpartition("@")
    base = base if at else boresight
    kind, _, arg = base.partition(":")
    kind = kind.strip().lower()
    if at:
        out = antenna_attrs(side, base, where, base_dir) if kind in ("horn", "table") else {}
        if not out:
            raise InputFileError(f"{side} {text!r}: a boresight (@AX,AY,AZ) is for horn and table antennas", path=where)
        axis = np.array([_number(a, f"{side} boresight", where) for a in boresight.split(",")])
        if axis.shape != (3,) or np.linalg.norm(axis) == 0:
            raise InputFileError(f"{side} {text!r}: a boresight is three numbers, not all zero", path=where)
        out[side] += "@" + ",".join(f"{a:g}" for a in axis / np.linalg.norm(axis))
        return out
    if kind == "isotropic" and not arg:
        return {side: "isotropic"}
    if kind == "dipole":
        axis = np.array([0.0, 0.0, 1.0]) if not arg else np.array(
            [_number(a, f"{side} dipole axis", where) for a in arg.split(",")])
        if axis.shape != (3,) or np.linalg.norm(axis) == 0:
            raise InputFileError(f"{side} {text!r}: a dipole axis is three numbers, not all zero", path=where)
        axis = axis / np.linalg.norm(axis)
        return {side: "dipole:" + ",".join(f"{a:g}" for a in axis)}
    if kind == "horn" and arg:
        hpbw = _number(arg, f"{side} horn beamwidth", where)
        if not 1.0 <= hpbw <= 180.0:
            raise InputFileError(f"{side} {text!r}: horn half-power beamwidth must be 1..180 deg", path=where)
        return {side: f"horn:{hpbw:g}"}
    if kind == "table" and arg:
        deg, gain = read_pattern_table(base_dir / arg.strip())
        return {side: f"table:{Path(arg.strip()).name}", f"{side}_table_deg": deg, f"{side}_table_gain_dbi": gain}
    raise InputFileError(f"{side} {text!r}: expected isotropic, dipole[:AX,AY,AZ], horn:HPBW_DEG[@AX,AY,AZ] or "
                         "table:FILE[@AX,AY,AZ]",
                         path=where)


def read_pattern_table(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """A pattern CSV (theta_deg,gain_dbi; angle off boresight rising from 0 to <= 180) -> two float arrays."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            rows = list(csv.DictReader(handle))
        deg = np.array([float(r["theta_deg"]) for r in rows])
        gain = np.array([float(r["gain_dbi"]) for r in rows])
    except FileNotFoundError:
        raise InputFileError("antenna table not found", path=path) from None
    except (KeyError, ValueError, TypeError, UnicodeDecodeError, csv.Error) as exc:
        raise InputFileError(f"antenna table needs columns theta_deg,gain_dbi with numbers ({exc})", path=path) from None
    if len(deg) < 2 or not np.all(np.isfinite(deg)) or not np.all(np.isfinite(gain)) or np.any(np.diff(deg) <= 0) \
            or deg[0] != 0 or deg[-1] > 180:
        raise InputFileError("antenna table: theta_deg must rise from 0 to at most 180 in >= 2 rows, finite gains",
                             path=path)
    return deg, gain


def resolve_setup(csv_path: Path, header: dict, flags: dict) -> MeasurementSetup:
    """Merge header < sidecar < flags (flags: key -> value or None) into artifact attributes."""
    sidecar, sidecar_path = sidecar_options(csv_path)
    merged, origin = {}, {}
    for name, source in (("header", header), ("sidecar", sidecar), ("flag", {k: v for k, v in flags.items() if v is not None})):
        for key, value in source.items():
            targets = ("antenna_tx", "antenna_rx") if key == "antenna" else (key,)
            for t in targets:
                merged[t], origin[t] = (value, name)
    where = str(sidecar_path if sidecar_path and "sidecar" in origin.values() else csv_path)
    setup = MeasurementSetup(origin=origin)
    for side in ("antenna_tx", "antenna_rx"):
        if side in merged:
            setup.attrs.update(antenna_attrs(side, merged[side], where, csv_path.parent))
    if "polarisation" in merged:
        pol = str(merged["polarisation"]).strip().upper()
        if pol not in POLARISATIONS:
            raise InputFileError(f"polarisation {merged['polarisation']!r}: expected V or H", path=where)
        setup.attrs["polarisation"] = pol
    if "tx_power_dbm" in merged:
        setup.attrs["tx_power_dbm"] = _number(merged["tx_power_dbm"], "tx_power_dbm", where)
    power = str(merged.get("power", "rssi" if "tx_power_dbm" in merged else "path_gain")).strip().lower()
    origin.setdefault("power", "default" if "tx_power_dbm" not in merged else origin["tx_power_dbm"])
    if power not in POWERS:
        raise InputFileError(f"power {merged['power']!r}: expected {', '.join(POWERS)}", path=where)
    if power == "rssi" and "tx_power_dbm" not in setup.attrs:
        raise InputFileError("power = rssi needs tx_power_dbm (the transmit power in dBm: pass --tx-power-dbm P)", path=where)
    if power != "rssi" and "tx_power_dbm" in setup.attrs:
        raise InputFileError(f"tx_power_dbm is given but power = {power} (tx_power_dbm goes with power = rssi)",
                             path=where)
    setup.attrs["power"] = power
    return setup


def boresight_gain(attrs: dict, side: str) -> float:
    """Linear gain of one recorded antenna toward its boresight (the object of a monostatic radar):
    1 for isotropic or unstated, 1.5 for a dipole (broadside), G0 = 2 (q + 1) for a horn, the table's
    0-degree value for a table."""
    text = str(attrs.get(side, "isotropic"))
    kind, _, arg = boresight_split(text)[0].partition(":")
    if kind == "dipole":
        return 1.5
    if kind == "horn":
        return float(horn_boresight_gain(float(arg)))
    if kind == "table":
        return float(10 ** (np.asarray(attrs[f"{side}_table_gain_dbi"], float)[0] / 10))
    return 1.0
