"""What an imported file is (its task) and whether its turntable columns agree with its positions.

Task rule (printed on import, docs/artifacts.md): no aspect_deg and no RCS -> "rssi"; otherwise
"wideband" when the frequencies form a dense band (at least WIDEBAND_MIN_FREQS of them, the largest
step between neighbours at most WIDEBAND_MAX_STEP_RATIO times the smallest), else "rcs" (one
frequency, or a few discrete ones: a multi-frequency narrowband set, one material fit over all).

Turntable convention (monostatic rows, tx and rx together): the object turns about the z axis
through x = y = 0, and aspect theta puts the radar at azimuth -theta (simulate's convention).
"""
from __future__ import annotations

import numpy as np

from rfir_core.errors import InputFileError

TASKS = ("rcs", "wideband", "rssi")
WIDEBAND_MIN_FREQS = 8
WIDEBAND_MAX_STEP_RATIO = 2.0
ASPECT_TOL_DEG = 1.0


def detect_task(present: list[str], freqs_hz: np.ndarray, forced: str | None, where: str) -> tuple[str, str]:
    """(task, the rule that chose it, in words). present: optional columns in the file; freqs_hz [F]."""
    f = np.sort(np.asarray(freqs_hz, np.float64))
    if forced is not None:
        if forced not in TASKS:
            raise InputFileError(f"task {forced!r}: expected {', '.join(TASKS)}", path=where)
        return forced, "as given by --task"
    if "aspect_deg" not in present and "rcs_dbsm" not in present:
        return "rssi", "no aspect_deg and no RCS column: links between placed antennas"
    if f.size < WIDEBAND_MIN_FREQS:
        return "rcs", (f"{f.size} discrete frequenc{'y' if f.size == 1 else 'ies'} (wideband needs >= "
                       f"{WIDEBAND_MIN_FREQS} in a dense band; --task wideband to insist)")
    steps = np.diff(f)
    if steps.max() <= WIDEBAND_MAX_STEP_RATIO * steps.min():
        return "wideband", (f"{f.size} frequencies in a dense band {f[0] / 1e9:g}-{f[-1] / 1e9:g} GHz (largest "
                            f"step <= {WIDEBAND_MAX_STEP_RATIO:g}x the smallest)")
    return "rcs", (f"{f.size} frequencies, unevenly spaced (largest step {steps.max() / 1e6:g} MHz > "
                   f"{WIDEBAND_MAX_STEP_RATIO:g}x the smallest {steps.min() / 1e6:g} MHz): a multi-frequency "
                   "narrowband set; --task wideband to insist")


def _wrap_deg(x: np.ndarray) -> np.ndarray:
    return (np.asarray(x) + 180.0) % 360.0 - 180.0


def check_turntable(data: dict, lines: np.ndarray, where: str) -> None:
    """Refuse monostatic rows whose aspect disagrees with where the positions put the radar.

    data: measurements datasets (tx_pos, rx_pos [L, 3] m, aspect_rad [L]); lines [L]: the CSV
    line of each link. Rows whose tx and rx are apart (bistatic) or that sit on the axis are not
    checked. Names the first disagreeing row and whether the sign or the zero is off."""
    tx, rx = np.asarray(data["tx_pos"], float), np.asarray(data["rx_pos"], float)
    mid = 0.5 * (tx + rx)
    radius = np.hypot(mid[:, 0], mid[:, 1])
    mono = (np.linalg.norm(tx - rx, axis=1) < 0.05 * radius) & (radius > 1e-3)
    if not mono.any():
        return
    aspect = np.degrees(np.asarray(data["aspect_rad"], float))[mono]
    azimuth = np.degrees(np.arctan2(mid[mono, 1], mid[mono, 0]))
    off = _wrap_deg(azimuth + aspect)                      # 0 where the convention holds
    bad = np.abs(off) > ASPECT_TOL_DEG
    if not bad.any():
        return
    first = int(np.flatnonzero(bad)[0])
    if np.all(np.abs(_wrap_deg(azimuth - aspect)) <= ASPECT_TOL_DEG):
        why = "the aspect turns the other way (sign): negate aspect_deg"
    elif np.all(np.abs(_wrap_deg(off - off[first])) <= ASPECT_TOL_DEG):
        why = (f"every row is off by the same {off[first]:+.1f} deg (zero of the turntable): "
               f"subtract {off[first]:.1f} from aspect_deg")
    elif np.all(np.abs(_wrap_deg(azimuth - aspect - _wrap_deg(azimuth - aspect)[first])) <= ASPECT_TOL_DEG):
        why = "the aspect turns the other way and its zero is offset: negate aspect_deg and shift it"
    else:
        why = "no single sign and offset explains the rows (positions not around x = y = 0?)"
    raise InputFileError(
        f"line {int(np.asarray(lines)[mono][first])}: aspect_deg {aspect[first]:g} but the positions put the radar "
        f"at azimuth {azimuth[first]:.1f} deg (convention: azimuth = -aspect about the z axis through x = y = 0); "
        f"{int(bad.sum())} of {int(mono.sum())} monostatic rows disagree: {why}; nothing written", path=where)
