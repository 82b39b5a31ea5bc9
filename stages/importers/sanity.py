"""Unit sanity of an imported file, checked before anything is written. Each check refuses with one
line naming the flag that fixes it (InputFileError):

- power_db all between 0 and 1 while read as dB: a linear power -> --power-unit mW or W.
- a path gain above MAX_PATH_GAIN_DB (a passive link cannot gain power), or below MIN_PATH_GAIN_DB
  (links without a range_m; radar rows at long range may be weaker) -> --power / --tx-power-dbm /
  --power-unit.
- rssi task: median link distance above MAX_MEDIAN_LINK_M when no position unit was given ->
  --position-unit cm.
- rssi task: path gain above free space (Friis at the link's distance and frequency, with the
  stated antennas' peak gains) by more than EXCESS_MEDIAN_DB at the median link or EXCESS_ANY_DB at
  any link, counting links at least one wavelength long -> --power rssi --tx-power-dbm P (or
  --tx-power-dbm, or --antenna).
"""
from __future__ import annotations

import numpy as np

from rfir_core.errors import InputFileError
from rfir_core.physics.closed_forms import friis_path_gain, wavelength_m

from .meas_setup import MeasurementSetup, boresight_gain

MAX_PATH_GAIN_DB = 10.0
MIN_PATH_GAIN_DB = -250.0
MAX_MEDIAN_LINK_M = 100.0
EXCESS_MEDIAN_DB = 6.0
EXCESS_ANY_DB = 20.0


def peak_gain(attrs: dict, side: str) -> float:
    """Largest linear gain of a recorded antenna (1 for isotropic or unstated; a table's largest value)."""
    key = f"{side}_table_gain_dbi"
    if str(attrs.get(side, "")).startswith("table:") and key in attrs:
        return float(10 ** (np.max(np.asarray(attrs[key], float)) / 10))
    return boresight_gain(attrs, side)


def _line(lines: np.ndarray, link: int) -> str:
    return f"line {int(np.asarray(lines)[link])}"


def check_power_values(raw_db: np.ndarray, setup: MeasurementSetup, power_unit_given: bool, where: str) -> None:
    """raw_db [L, F]: the power_db column as read (dB). A column of values all in (0, 1) read as dB is
    refused when it should be path gain or received power."""
    if power_unit_given or setup.power == "rcs":
        return
    if raw_db.size and np.all((raw_db > 0) & (raw_db < 1)):
        raise InputFileError("power_db values all lie between 0 and 1, which looks like a linear power, not dB: "
                             "pass --power-unit mW or --power-unit W (with --tx-power-dbm P), nothing written",
                             path=where)


def check_path_gain_range(data: dict, setup: MeasurementSetup, lines: np.ndarray, where: str) -> None:
    """Refuse a path gain [dB] outside the physical range (module docstring)."""
    pg = np.asarray(data["path_gain_db"], float)
    if not pg.size:
        return
    link, f = np.unravel_index(int(np.argmax(pg)), pg.shape)
    if pg[link, f] > MAX_PATH_GAIN_DB:
        if setup.power == "rssi":
            fix = (f"power_db minus the transmit power {setup.attrs['tx_power_dbm']:g} dBm: check --tx-power-dbm "
                   "and --power-unit")
        elif setup.power == "rcs":
            fix = "from the RCS by the radar equation: check --power, --power-unit and range_m"
        else:
            fix = ("read as path gain: received power in dBm? pass --power rssi --tx-power-dbm P; a path loss? "
                   "negate power_db")
        raise InputFileError(f"{_line(lines, link)}: path gain {pg[link, f]:+.1f} dB is above {MAX_PATH_GAIN_DB:+g} dB "
                             f"(a passive link cannot gain power) ({fix}), nothing written", path=where)
    weak = pg if "range_m" not in data else pg[:0]
    if weak.size and weak.min() < MIN_PATH_GAIN_DB:
        link, f = np.unravel_index(int(np.argmin(weak)), weak.shape)
        raise InputFileError(f"{_line(lines, link)}: path gain {weak[link, f]:.1f} dB is below {MIN_PATH_GAIN_DB:g} dB, "
                             "outside a physical range: check --power-unit (dB, dBm, mW, W), --power and "
                             "--tx-power-dbm, nothing written", path=where)


def link_distances(data: dict) -> np.ndarray:
    """[L] transmitter-receiver distance [m]."""
    return np.linalg.norm(np.asarray(data["tx_pos"], float) - np.asarray(data["rx_pos"], float), axis=1)


def check_link_distances(data: dict, position_unit_given: bool, where: str) -> None:
    """rssi task: refuse a median link distance above MAX_MEDIAN_LINK_M unless a position unit was given."""
    d = link_distances(data)
    if position_unit_given or not d.size:
        return
    median = float(np.median(d))
    if median > MAX_MEDIAN_LINK_M:
        raise InputFileError(f"the median link is {median:.0f} m long, which looks like centimetres for links in a "
                             "room: pass --position-unit cm (or --position-unit m if the links really are that "
                             "long), nothing written", path=where)


def free_space_excess(data: dict, setup: MeasurementSetup) -> np.ndarray:
    """[L, F] path gain above Friis [dB] at each link's distance and frequency with the antennas' peak
    gains; NaN for links shorter than one wavelength (no far field to compare with)."""
    d = link_distances(data)[:, None]
    f = np.asarray(data["freq_hz"], float)[None]
    gain = peak_gain(setup.attrs, "antenna_tx") * peak_gain(setup.attrs, "antenna_rx")
    with np.errstate(divide="ignore"):
        free = 10 * np.log10(friis_path_gain(np.maximum(d, 1e-12), f, gain, 1.0))
    excess = np.asarray(data["path_gain_db"], float) - free
    return np.where(d >= wavelength_m(f), excess, np.nan)


def check_free_space(data: dict, setup: MeasurementSetup, lines: np.ndarray, where: str) -> None:
    """rssi task: refuse path gains well above free space (module docstring), naming the fix."""
    excess = free_space_excess(data, setup)
    if not np.isfinite(excess).any():
        return
    median = float(np.nanmedian(excess))
    worst = float(np.nanmax(excess))
    if median <= EXCESS_MEDIAN_DB and worst <= EXCESS_ANY_DB:
        return
    link = int(np.unravel_index(int(np.nanargmax(excess)), excess.shape)[0])
    stats = (f"path gain is {median:+.1f} dB above free space at the median link and {worst:+.1f} dB at "
             f"{_line(lines, link)} (Friis at each link's distance and frequency)")
    if setup.power == "rssi":
        fix = (f"power_db minus the transmit power {setup.attrs['tx_power_dbm']:g} dBm: check --tx-power-dbm "
               "and --position-unit, or state high-gain antennas with --antenna")
    else:
        fix = ("power_db looks like received power in dBm, not path gain: pass --power rssi --tx-power-dbm P "
               "(or state high-gain antennas with --antenna)")
    raise InputFileError(f"{stats}: {fix}, nothing written", path=where)


def check_units(data: dict, raw_db: np.ndarray, setup: MeasurementSetup, task: str, lines: np.ndarray,
                given: frozenset, where: str) -> None:
    """Every check of the module docstring, in order: linear power, physical range, (rssi task) link
    lengths, free space. given: the unit flags stated ("power", "position")."""
    check_power_values(raw_db, setup, "power" in given, where)
    check_path_gain_range(data, setup, lines, where)
    if task == "rssi":
        check_link_distances(data, "position" in given, where)
        check_free_space(data, setup, lines, where)
