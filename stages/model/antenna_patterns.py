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
from rfir_core.physics.antennas import boresight_split, horn_boresight_gain, horn_exponent
from rfir_core.physics.polarisation import antenna_polarisation

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
    # a stated boresight (horn:HPBW@AX,AY,AZ) is the room model's (end_antenna); rcs antennas point at the object
    kind, _, arg = boresight_split(str(text))[0].partition(":")
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


# ---------------------------------------------------------------------------------------------------
# antennas of the room model (RSSI links): one pattern per end, in the room's frame, its axis stated once or per link
# ---------------------------------------------------------------------------------------------------
VERTICAL = (0.0, 0.0, 1.0)
SIDES = ("tx", "rx")


def unit_axis(text: str, what: str, where: str) -> tuple:
    """Three comma-separated numbers, not all zero, as a unit vector (a tuple of 3 floats); a one-line ConfigError
    naming `where` and `what` otherwise."""
    try:
        axis = np.array([float(a) for a in text.split(",")])
    except ValueError:
        axis = np.zeros(0)
    if axis.shape != (3,) or not np.isfinite(axis).all() or np.linalg.norm(axis) == 0:
        raise ConfigError(f"{where}: {what}: an axis is three numbers, not all zero")
    return tuple(float(a) for a in axis / np.linalg.norm(axis))


@dataclass(frozen=True)
class EndAntenna:
    """The antenna at one end of the room model's links (every transmitter, or every receiver): a pattern and the
    unit axis [3] it is symmetric about, in the room's frame: a dipole's axis (dipole:AX,AY,AZ), a horn's or a
    table's boresight (horn:HPBW@AX,AY,AZ; +z, the zenith, when none is stated). A link may carry its own axis
    (LinkAxes), which then replaces this one for that link."""

    pattern: AntennaPattern = field(default_factory=AntennaPattern)
    axis: tuple = VERTICAL

    @property
    def isotropic(self) -> bool:
        return self.pattern.kind == "isotropic"

    def _axes(self, count: int, axes) -> np.ndarray:
        """Unit axes [count, 3]: `axes` (one per direction) or this end's axis for every direction."""
        if axes is None:
            return np.broadcast_to(np.asarray(self.axis, np.float64), (count, 3))
        return np.asarray(axes, np.float64).reshape(count, 3)

    def gain(self, directions: np.ndarray, axes: np.ndarray | None = None) -> np.ndarray:
        """Linear power gain [N] toward unit directions [N, 3] leaving the antenna (AntennaPattern.gain), about
        unit axes [N, 3] (one per direction: its link's) or, when None, about this end's axis."""
        d = torch.as_tensor(np.asarray(directions, dtype=np.float64).reshape(-1, 3))
        return self.pattern.gain(d, torch.as_tensor(np.ascontiguousarray(self._axes(len(d), axes)))).numpy()

    def field_direction(self, directions: np.ndarray, polarisation: str, axes: np.ndarray | None = None) -> np.ndarray:
        """Unit field direction [N, 3] of the wave the antenna sends or receives along unit directions [N, 3]: a
        dipole's is its axis across the direction, unit(k (k . a) - a), for axes a [N, 3] (None: this end's; for the
        vertical dipole exactly the V direction of rfir_core.physics.polarisation); any other pattern's is
        `polarisation`'s ("V" or "H")."""

        k = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        room = antenna_polarisation(k, "V" if self.pattern.kind == "dipole" else polarisation)
        if self.pattern.kind != "dipole" or (axes is None and self.axis == VERTICAL):
            return room
        a = self._axes(len(k), axes)
        across = k * (k * a).sum(1, keepdims=True) - a
        norm = np.linalg.norm(across, axis=1, keepdims=True)
        # along the axis the dipole sends nothing (gain 0): any direction across k serves
        return np.where(norm > 1e-9, across / np.maximum(norm, 1e-300), room)

    def text(self) -> str:
        """The measurement set-up's spelling: isotropic, dipole:AX,AY,AZ, horn:HPBW or table, a horn's or table's
        boresight other than +z after "@"."""
        axis = ",".join(f"{a:g}" for a in self.axis)
        if self.pattern.kind == "dipole":
            return "dipole:" + axis
        turned = self.pattern.kind in ("horn", "table") and self.axis != VERTICAL
        return self.pattern.text() + (f"@{axis}" if turned else "")

    def attrs(self, side: str) -> dict:
        """{side: text} and, for a table, its angles and gains in dBi (the measurements' attributes, docs/artifacts.md)."""
        out = {side: self.text()}
        if self.pattern.kind == "table":
            out[f"{side}_table_deg"] = np.asarray(self.pattern.table_deg, float)
            out[f"{side}_table_gain_dbi"] = 10 * np.log10(np.maximum(np.asarray(self.pattern.table_gain, float), 1e-30))
        return out


def end_antenna(attrs: dict, side: str, where: str) -> EndAntenna | None:
    """The antenna `attrs` (a measurements artifact's, or a room model's) state for `side` ("antenna_tx" /
    "antenna_rx"), None when they state none; a one-line ConfigError naming `where` for one the room cannot take."""
    text = attrs.get(side)
    if text is None:
        return None
    base, boresight = boresight_split(str(text))
    kind, _, arg = base.partition(":")
    if kind == "dipole" and arg:
        return EndAntenna(AntennaPattern("dipole"), unit_axis(arg, f"{side} = {text}", where))
    if kind == "table" and f"{side}_table_deg" not in attrs:
        raise ConfigError(f"{where}: {side} = {text} but no {side}_table_deg / {side}_table_gain_dbi: re-import it")
    axis = unit_axis(boresight, f"{side} = {text}", where) if boresight else VERTICAL
    return EndAntenna(recorded_antenna(attrs, side, where), axis)


@dataclass(frozen=True, eq=False)
class LinkAxes:
    """Antenna axes per link (the measurements' tx_axis / rx_axis): tx, rx [M, 3] unit vectors in the room's frame
    (a dipole's axis, a horn's or table's boresight), None for a side whose links take its EndAntenna's axis."""

    tx: np.ndarray | None = None
    rx: np.ndarray | None = None

    @property
    def sides(self) -> tuple[str, ...]:
        """The sides ("tx", "rx") with axes per link."""
        return tuple(s for s in SIDES if getattr(self, s) is not None)

    def rows(self, rows) -> "LinkAxes":
        """The axes of links `rows` (an index array, a boolean mask or a slice)."""
        return LinkAxes(*(None if a is None else a[rows] for a in (self.tx, self.rx)))

    def check_count(self, count: int, where: str) -> None:
        """A one-line ConfigError unless every side given has `count` axes."""
        for s in self.sides:
            if len(getattr(self, s)) != count:
                raise ConfigError(f"{where}: {len(getattr(self, s))} {s} axes for {count} links")


def link_axes(meas, where: str) -> LinkAxes:
    """The axes per link a measurements artifact holds (datasets tx_axis, rx_axis [L, 3]), normalised; a one-line
    InputFileError naming the dataset for a row that is not finite or is all zero."""
    out = {}
    for side in SIDES:
        raw = meas.get(f"{side}_axis")
        if raw is None:
            continue
        axis = np.asarray(raw, np.float64).reshape(-1, 3)
        norm = np.linalg.norm(axis, axis=1)
        bad = np.flatnonzero(~np.isfinite(norm) | (norm == 0))
        if bad.size:
            raise InputFileError(f"{side}_axis row {int(bad[0])} is {'zero' if np.isfinite(norm[bad[0]]) else 'not finite'}"
                                 f" ({bad.size} such rows): an axis is a unit vector", path=where)
        out[side] = axis / norm[:, None]
    return LinkAxes(out.get("tx"), out.get("rx"))


@dataclass(frozen=True)
class RoomAntennas:
    """The room model's antennas: tx at every transmitter, rx at every receiver; per_link: the sides whose axis is
    each link's own (LinkAxes, from the measurements); source: why (printed, recorded). A specular path's field is
    weighted by sqrt(G_tx(departure)) sqrt(G_rx(arrival)), a diffuse cell's power by G_tx toward the cell and G_rx
    toward it from the receiver (docs/physics.md 8.10)."""

    tx: EndAntenna = field(default_factory=EndAntenna)
    rx: EndAntenna = field(default_factory=EndAntenna)
    source: str = field(default="", compare=False)
    per_link: tuple = ()

    @property
    def isotropic(self) -> bool:
        return self.tx.isotropic and self.rx.isotropic

    def words(self) -> str:
        """As rf-fit prints it: 'antennas tx dipole:0,0,1 (axis per link), rx isotropic (stated by the measurements)'."""
        ends = [f"{s} {getattr(self, s).text()}" + (" (axis per link)" if s in self.per_link else "") for s in SIDES]
        what = "isotropic antennas" if self.isotropic else "antennas " + ", ".join(ends)
        return what + (f" ({self.source})" if self.source else "")

    def attrs(self) -> dict:
        """The model attributes that record them (read back by from_attrs)."""
        return {**self.tx.attrs("antenna_tx"), **self.rx.attrs("antenna_rx"), "antenna_source": self.source,
                "antenna_axes_per_link": ",".join(self.per_link)}

    @classmethod
    def from_attrs(cls, attrs: dict, where: str = "the model") -> "RoomAntennas":
        """The antennas a room model records (attrs); isotropic where it records none (models fitted before)."""
        ends = [end_antenna(attrs, side, where) or EndAntenna() for side in ("antenna_tx", "antenna_rx")]
        per_link = tuple(s for s in str(attrs.get("antenna_axes_per_link", "")).split(",") if s in SIDES)
        return cls(*ends, source=str(attrs.get("antenna_source", "")), per_link=per_link)

    def oriented(self, axes: LinkAxes) -> "RoomAntennas":
        """These antennas with the sides of `axes` oriented per link, where their pattern has an axis (an isotropic
        end has none: its axes are not used)."""
        sides = tuple(s for s in axes.sides if not getattr(self, s).isotropic)
        return replace(self, per_link=sides)


def room_antennas(config: dict, meas, where: str, axes: LinkAxes = LinkAxes()) -> RoomAntennas:
    """The antennas an RSSI fit's room model uses, source saying why. rf_fit.antenna other than "auto": that pattern
    at both ends (a dipole vertical); "auto": each side as the measurements state it (one side unstated:
    isotropic there, said), else isotropic (said so). A side whose links carry their own axis (the measurements'
    tx_axis / rx_axis: `axes`, as link_axes reads them) is oriented per link unless its pattern is isotropic (said
    so)."""
    kind = str(config.get("antenna", "auto"))
    if kind != "auto":
        end = EndAntenna(resolve_antenna(kind, float(config.get("horn_hpbw_deg", 40.0)),
                                         str(config.get("antenna_table", "")), None, "rssi"))
        return _with_axes(RoomAntennas(end, end, source="rf_fit.antenna"), axes)
    tx, rx = (end_antenna(meas.attrs, side, where) for side in ("antenna_tx", "antenna_rx"))
    if tx is None and rx is None:
        return _with_axes(RoomAntennas(source="assumed: the measurements state no antenna; state it on import "
                                              "(docs/artifacts.md) or set rf_fit.antenna"), axes)
    unstated = [side for side, end in (("antenna_tx", tx), ("antenna_rx", rx)) if end is None]
    return _with_axes(RoomAntennas(tx or EndAntenna(), rx or EndAntenna(),
                                   source="stated by the measurements" + (f"; {unstated[0]} not stated: isotropic "
                                                                          "assumed" if unstated else "")), axes)


def _with_axes(antennas: RoomAntennas, axes: LinkAxes) -> RoomAntennas:
    """`antennas` oriented per link by the measurements' axes, the source saying which side's were used or not."""
    out = antennas.oriented(axes)
    unused = [s for s in axes.sides if s not in out.per_link]
    notes = ([f"{', '.join(out.per_link)} axis per link ({', '.join(f'{s}_axis' for s in out.per_link)})"]
             if out.per_link else []) + ([f"{', '.join(f'{s}_axis' for s in unused)} not used (isotropic)"]
                                         if unused else [])
    return replace(out, source="; ".join([out.source] + notes) if notes else out.source)
