"""Units and column names of an imported CSV: `--power-unit`, `--freq-unit`, `--position-unit`
(or `--position-scale`) and `--column NAME=CSVNAME`.

- power unit: "dB" (the default: power_db is already logarithmic; what it holds is the set-up's
  `power`), "dBm" (received power [dBm], so power = rssi), "mW" or "W" (received power, linear,
  converted to dBm on import: 10 log10(P / 1 mW)).
- frequency unit: the freq_hz column is in Hz, kHz, MHz or GHz (multiplied into Hz on import).
- position unit: coordinates and ranges in m, cm or mm (multiplied into metres on import);
  `--position-scale S` is the same as a factor S (metres per file unit), and must be positive.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

from rfir_core.errors import ConfigError

POWER_UNITS = ("dB", "dBm", "mW", "W")
RECEIVED_POWER_UNITS = ("dBm", "mW", "W")       # these make power_db received power (power = rssi)
FREQ_UNITS = {"Hz": 1.0, "kHz": 1e3, "MHz": 1e6, "GHz": 1e9}
POSITION_UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}


@dataclass(frozen=True)
class Units:
    """Resolved units. power: one of POWER_UNITS; freq_scale [Hz per file unit]; position_scale
    [m per file unit]; given: the flags the user stated ("power", "freq", "position")."""

    power: str = "dB"
    freq_scale: float = 1.0
    position_scale: float = 1.0
    given: frozenset = field(default_factory=frozenset)

    @property
    def freq_name(self) -> str:
        return next(k for k, v in FREQ_UNITS.items() if v == self.freq_scale)

    def to_dbm(self, value: float) -> float:
        """A power_db cell in this unit -> dB (dB and dBm unchanged; mW, W -> dBm). NaN for a
        non-positive linear power."""
        if self.power in ("dB", "dBm"):
            return value
        if not value > 0.0:
            return math.nan
        return 10.0 * math.log10(value) + (30.0 if self.power == "W" else 0.0)


def _choice(text: str, choices, flag: str) -> str:
    for c in choices:
        if text.strip().lower() == c.lower():
            return c
    raise ConfigError(f"{flag} {text!r}: expected {', '.join(choices)}")


def resolve_units(power_unit: str | None = None, freq_unit: str | None = None, position_unit: str | None = None,
                  position_scale: float | None = None) -> Units:
    """Units from the import flags (None: not given). Raises ConfigError (exit 4) for an unknown unit,
    a non-positive or non-finite --position-scale, or a --position-scale that contradicts --position-unit."""
    given = set()
    power = "dB"
    if power_unit is not None:
        power = _choice(power_unit, POWER_UNITS, "--power-unit")
        given.add("power")
    freq_scale = 1.0
    if freq_unit is not None:
        freq_scale = FREQ_UNITS[_choice(freq_unit, tuple(FREQ_UNITS), "--freq-unit")]
        given.add("freq")
    scale = check_position_scale(position_scale) if position_scale is not None else None
    if position_unit is not None:
        by_unit = POSITION_UNITS[_choice(position_unit, tuple(POSITION_UNITS), "--position-unit")]
        if scale is not None and not math.isclose(scale, by_unit, rel_tol=1e-9):
            raise ConfigError(f"--position-unit {position_unit} (scale {by_unit:g}) and --position-scale {scale:g} "
                              "disagree: give one of them")
        scale = by_unit
    if scale is not None:
        given.add("position")
    return Units(power, freq_scale, 1.0 if scale is None else scale, frozenset(given))


def check_position_scale(scale: float) -> float:
    """A --position-scale [m per file unit]: positive and finite, else ConfigError."""
    if not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale > 0):
        raise ConfigError(f"--position-scale {scale:g}: must be a positive number of metres per file unit "
                          "(0.01 for centimetres, 0.001 for millimetres; or --position-unit cm|mm)")
    return float(scale)


def parse_columns(specs: list[str] | None, known: tuple[str, ...]) -> dict[str, str]:
    """`--column NAME=CSVNAME` texts -> {NAME: CSVNAME}. NAME must be one of `known` (rfir's column
    names), each at most once; ConfigError otherwise."""
    out: dict[str, str] = {}
    for spec in specs or []:
        name, sep, source = (s.strip() for s in str(spec).partition("="))
        if not sep or not name or not source:
            raise ConfigError(f"--column {spec!r}: expected NAME=CSVNAME (e.g. --column power_db=rssi)")
        if name not in known:
            raise ConfigError(f"--column {spec!r}: {name!r} is not an rfir column (known: {', '.join(known)})")
        if name in out:
            raise ConfigError(f"--column {name}= is given twice ({out[name]!r} and {source!r})")
        out[name] = source
    return out
