"""Antenna power patterns for the renderer: isotropic, dipole, horn (same as simulate), tabulated.

All patterns are rotationally symmetric about an axis (boresight for horn/table, the dipole's
axis for the dipole). `gain(directions, axis)` returns linear power gain (relative to isotropic)
toward unit directions [..., 3] leaving the antenna; `axis` [..., 3] broadcasts against them.
The field pattern C_R of docs/physics.md section 5.1 (step 3) is sqrt(gain).
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
import torch

from rfir_core.errors import ConfigError, InputFileError
from rfir_core.physics.antennas import horn_boresight_gain, horn_exponent

KINDS = ("isotropic", "dipole", "horn", "table")


@dataclass(frozen=True)
class AntennaPattern:
    """A rotationally symmetric antenna pattern.

    kind: "isotropic", "dipole" (1.5 sin^2 of the angle to the axis), "horn" (G0 cos^q over the
    front hemisphere, exactly rfir_core.physics.antennas), or "table".
    hpbw_deg: horn half-power beamwidth [deg]. table_deg / table_gain: tabulated pattern, angle off
    boresight [deg] ascending and linear gain (use `from_table_file`).
    """

    kind: str = "isotropic"
    hpbw_deg: float = 40.0
    table_deg: tuple = field(default_factory=tuple)
    table_gain: tuple = field(default_factory=tuple)
    source: str = field(default="", compare=False)   # why this pattern (antenna_choice), recorded in artifacts

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ConfigError(f"antenna kind {self.kind!r} unknown (known: {', '.join(KINDS)})")

    @property
    def boresight_gain(self) -> float:
        """Linear gain on boresight (G0 in the radar equation)."""
        if self.kind == "horn":
            return float(horn_boresight_gain(self.hpbw_deg))
        if self.kind == "dipole":
            return 1.5
        if self.kind == "table":
            return float(self.table_gain[0])
        return 1.0

    @property
    def front_only(self) -> bool:
        """True when the pattern is zero behind the antenna (the receiver grid covers 2 pi sr)."""
        return self.kind == "horn" or (self.kind == "table" and self.table_deg[-1] <= 90.0)

    def gain(self, directions: torch.Tensor, axis: torch.Tensor) -> torch.Tensor:
        """Linear power gain toward unit `directions` [..., 3] for unit `axis` [..., 3]."""
        cos_t = (directions * axis).sum(-1).clamp(-1.0, 1.0)
        if self.kind == "isotropic":
            return torch.ones_like(cos_t)
        if self.kind == "dipole":
            return 1.5 * (1.0 - cos_t**2)
        if self.kind == "horn":
            q = horn_exponent(self.hpbw_deg)
            return torch.where(cos_t > 0, horn_boresight_gain(self.hpbw_deg) * cos_t.clamp(min=0.0) ** q,
                               torch.zeros_like(cos_t))
        theta = torch.rad2deg(torch.arccos(cos_t)).detach().cpu().numpy()
        g = np.interp(theta, np.asarray(self.table_deg), np.asarray(self.table_gain), right=0.0)
        return torch.as_tensor(g, dtype=cos_t.dtype, device=cos_t.device)

    def describe(self) -> dict:
        """Attributes recorded in artifacts (model/ group)."""
        out = {"antenna_kind": self.kind, "antenna_boresight_gain": self.boresight_gain}
        if self.kind == "horn":
            out["antenna_hpbw_deg"] = float(self.hpbw_deg)
        if self.kind == "table":
            out.update(antenna_table_deg=np.asarray(self.table_deg, float),
                       antenna_table_gain=np.asarray(self.table_gain, float))
        if self.source:
            out["antenna_source"] = self.source
        return out

    def text(self) -> str:
        """The measurement set-up's spelling: isotropic, dipole:0,0,1, horn:HPBW or table."""
        return {"horn": f"horn:{self.hpbw_deg:g}", "dipole": "dipole:0,0,1"}.get(self.kind, self.kind)

    def note(self) -> str:
        """One line for logs: 'antenna horn:40 (the simulator's)'."""
        return f"antenna {self.text()}" + (f" ({self.source})" if self.source else "")


def antenna_from_attrs(attrs: dict) -> AntennaPattern:
    """The pattern recorded by `AntennaPattern.describe` in an artifact's model attributes."""
    kind = str(attrs.get("antenna_kind", "isotropic"))
    if kind == "table":
        return AntennaPattern("table", table_deg=tuple(np.asarray(attrs["antenna_table_deg"], float)),
                              table_gain=tuple(np.asarray(attrs["antenna_table_gain"], float)))
    return AntennaPattern(kind, hpbw_deg=float(attrs.get("antenna_hpbw_deg", 40.0)))


def recorded_antenna(attrs: dict, side: str, where: str) -> AntennaPattern | None:
    """The pattern a measurements artifact states for `side` ("antenna_tx" / "antenna_rx"), None when
    it states none (attributes written by rfir import, rfir_stages.importers.meas_setup)."""
    text = attrs.get(side)
    if text is None:
        return None
    kind, _, arg = str(text).partition(":")
    if kind == "horn":
        return AntennaPattern("horn", hpbw_deg=float(arg))
    if kind == "table":
        gain = 10.0 ** (np.asarray(attrs[f"{side}_table_gain_dbi"], float) / 10.0)
        return AntennaPattern("table", table_deg=tuple(np.asarray(attrs[f"{side}_table_deg"], float)),
                              table_gain=tuple(gain))
    if kind == "dipole" and arg and not np.allclose([float(a) for a in arg.split(",")], [0.0, 0.0, 1.0]):
        raise ConfigError(f"{where}: {side} = {text}: rf-fit models dipoles along z only (vertical); "
                          "re-import with dipole:0,0,1 or set rf_fit.antenna")
    return AntennaPattern(kind)


def antenna_choice(config: dict, meas, task: str, where: str) -> AntennaPattern:
    """The pattern an rf fit uses, its `source` saying why (printed and recorded). rf_fit.antenna other than "auto" wins;
    "auto": the antennas the measurements state (one pattern for both sides), else the simulator's
    horn for simulated rcs/wideband data, else isotropic (said so)."""
    kind = str(config.get("antenna", "auto"))
    if kind != "auto":
        ant = resolve_antenna(kind, float(config.get("horn_hpbw_deg", 40.0)), str(config.get("antenna_table", "")),
                              None, task)
        return replace(ant, source="rf_fit.antenna")
    tx, rx = (recorded_antenna(meas.attrs, side, where) for side in ("antenna_tx", "antenna_rx"))
    if tx is not None or rx is not None:
        if tx != rx:
            raise ConfigError(f"{where}: antenna_tx {meas.attrs.get('antenna_tx', 'unstated')} and antenna_rx "
                              f"{meas.attrs.get('antenna_rx', 'unstated')} differ: rf-fit fits one pattern for both "
                              "sides; state the same antenna for both, or set rf_fit.antenna")
        if tx.kind == "dipole" and task in ("rcs", "wideband"):
            raise ConfigError(f"{where}: a dipole on a monostatic radar: rf-fit points rcs antennas at the object "
                              "(boresight), which a dipole does not have; state isotropic, horn or table")
        return replace(tx, source="stated by the measurements")
    simulator = meas.free.get("simulator@attrs", {})
    if simulator:
        ant = resolve_antenna("auto", float(config.get("horn_hpbw_deg", 40.0)), "", simulator, task)
        return replace(ant, source="the simulator's")
    return AntennaPattern("isotropic", source="assumed: the measurements state no antenna; state it on import "
                                              "(docs/artifacts.md) or set rf_fit.antenna")


def from_table_file(path: str | Path) -> AntennaPattern:
    """Read a tabulated pattern: CSV with header `theta_deg,gain_dbi` (angle off boresight, ascending)."""
    path = Path(path)
    try:
        with open(path, newline="") as handle:
            rows = list(csv.DictReader(handle))
        deg = np.array([float(r["theta_deg"]) for r in rows])
        gain = 10 ** (np.array([float(r["gain_dbi"]) for r in rows]) / 10)
    except FileNotFoundError:
        raise InputFileError("antenna table not found", path=path) from None
    except (KeyError, ValueError) as exc:
        raise InputFileError(f"antenna table needs columns theta_deg,gain_dbi with numbers ({exc})", path=path) from None
    if len(deg) < 2 or np.any(np.diff(deg) <= 0) or deg[0] != 0 or deg[-1] > 180:
        raise InputFileError("antenna table: theta_deg must rise from 0 to at most 180 in >= 2 rows", path=path)
    return AntennaPattern("table", table_deg=tuple(deg), table_gain=tuple(gain))


def resolve_antenna(kind: str, hpbw_deg: float, table: str, simulator_attrs: dict | None, task: str) -> AntennaPattern:
    """The pattern to use. kind "auto": the horn (beamwidth from the measurement's simulator
    attributes when recorded) for rcs/wideband tasks, isotropic otherwise."""
    if kind == "auto":
        if task in ("rcs", "wideband"):
            attrs = simulator_attrs or {}
            q = attrs.get("horn_q", attrs.get("rcs.horn_q"))
            hpbw = float(attrs.get("rcs.horn_hpbw_deg", attrs.get("horn_hpbw_deg", hpbw_deg)))
            if q is not None and "horn_hpbw_deg" not in attrs and "rcs.horn_hpbw_deg" not in attrs:
                hpbw = 2 * math.degrees(math.acos(0.5 ** (1.0 / float(q))))
            return AntennaPattern("horn", hpbw_deg=hpbw)
        return AntennaPattern("isotropic")
    if kind == "table":
        return from_table_file(table)
    return AntennaPattern(kind, hpbw_deg=hpbw_deg)
