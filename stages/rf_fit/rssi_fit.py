"""`rfir rf-fit` for RSSI measurements (task "rssi"): the physical room model (room_stage.py).

Called by stage.run when the measurement file's task is "rssi". Checks the request, picks the
training rows (`[rf_fit.rssi] split`, rssi_split.py), the frequency column, the training targets and the
antennas (as the measurements state them per side, antenna_patterns.room_antennas), then fits the room model
(docs/physics.md section 8.10) and writes its `rf` artifact.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from rfir_core.errors import ConfigError, InputFileError, StageError
from rfir_core.progress import NullProgress

from rfir_stages.model.antenna_patterns import link_axes, room_antennas
from rfir_stages.model.links import check_overlap, geometry_from_artifact, inside_words, positions_inside
from .room_stage import run_room
from .rssi_split import rssi_settings, training_rows


def run_rssi(scene, meas, scene_path: Path, measurements_path: Path, out_path: Path, config: dict, render_cfg,
             fit_cfg=None, *, seed: int = 0, config_toml: str = "", progress=None):
    """Fit the room model to the RSSI links of `meas`; see the module docstring. config: the [rf_fit] table.
    fit_cfg (rf-fit's FitConfig) is not used: the room model's optimiser settings are [rf_fit.physical].
    Returns stage.RfFitResult."""

    progress = progress or NullProgress()
    t_start = time.time()
    cfg = rssi_settings(config)
    if str(config.get("split", "data")) != "data":
        raise ConfigError(f"rf_fit.split = {config['split']!r} is for rcs data; RSSI data uses rf_fit.rssi.split "
                          "('file' or 'holdout_tx')")
    where = str(measurements_path)
    axes = link_axes(meas, where)                   # each link's antenna axes, where the measurements hold them
    antennas = room_antennas(config, meas, where, axes)   # each end's pattern, weighting every path (RoomGeometry.links)
    geom = geometry_from_artifact(scene)
    check_overlap(geom, meas, where)
    check_positions_in_extent(geom, meas, where)
    if cfg["split"] == "file" and meas.get("split") is None:
        rows, held = np.arange(len(np.asarray(meas["tx_pos"]))), np.zeros(0, np.int64)
        progress.log("the measurements have no split column: every link trains the model and none is held out "
                     "to score it (rfir import csv --split random:0.2 holds links out)")
    else:
        rows, held = training_rows(meas, cfg, seed, where)
    rows = _rows_with_length(meas, rows, where, progress)
    freqs = np.asarray(meas["freq_hz"], np.float64)
    col = 0
    if config.get("freqs_hz"):
        hit = np.flatnonzero(np.abs(freqs - float(config["freqs_hz"][0])) <= 1e-6 * freqs)
        if hit.size == 0:
            raise StageError(f"frequency {config['freqs_hz'][0]:g} Hz is not in the file", path=where)
        col = int(hit[0])
    max_links = int(config.get("max_links", 0))
    if max_links and len(rows) > max_links:
        rows = rows[np.linspace(0, len(rows) - 1, max_links).round().astype(int)]
    rows = _rows_clear_of_geometry(geom, meas, rows, where, float(config.get("min_clearance_m", 0.02)), progress)
    tx, rx = np.asarray(meas["tx_pos"])[rows], np.asarray(meas["rx_pos"])[rows]
    target_db = np.asarray(meas["path_gain_db"], np.float64)[rows, col]
    if not np.isfinite(target_db).all():
        raise InputFileError("path_gain_db has non-finite training values", path=measurements_path)
    return run_room(scene, meas, geom, rows, held, tx, rx, float(freqs[col]), target_db, scene_path,
                    measurements_path, out_path, config, render_cfg, cfg, seed=seed, config_toml=config_toml,
                    progress=progress, t_start=t_start, antennas=antennas, axes=axes.rows(rows))


MIN_LINK_M = 1e-3   # a transmitter and a receiver closer than this are one point: no direction, no path


def _rows_with_length(meas, rows: np.ndarray, where: str, progress) -> np.ndarray:
    """The rows whose transmitter and receiver are at least MIN_LINK_M apart; the others (a link from a point
    to itself) are left out with a warning that counts them, and a file of only such links is refused."""
    length = np.linalg.norm(np.asarray(meas["tx_pos"])[rows] - np.asarray(meas["rx_pos"])[rows], axis=1)
    short = length < MIN_LINK_M
    if not short.any():
        return rows
    if short.all():
        raise InputFileError("every training link has its transmitter at its receiver (closer than 1 mm)", path=where)
    progress.log(f"warning: {where}: {int(short.sum())} of {len(rows)} training links have the transmitter at the "
                 f"receiver (closer than 1 mm; the first is row {int(rows[short][0])}): left out")
    return rows[~short]


def check_positions_in_extent(geom, meas, where: str, share: float = 0.5) -> None:
    """Refuse measurements whose antennas mostly lie far outside the geometry's extent (the Gaussians' box grown
    by a quarter of its size and 1 m each way): positions in another unit (cm, mm) or of another scene."""
    lo, hi = geom.means.min(0).values.numpy(), geom.means.max(0).values.numpy()
    grow = 0.25 * (hi - lo) + 1.0
    pts = np.concatenate([np.asarray(meas["tx_pos"], np.float64), np.asarray(meas["rx_pos"], np.float64)])
    outside = np.any((pts < lo - grow) | (pts > hi + grow), axis=1)
    if outside.mean() <= share:
        return
    reach = float(np.abs(pts).max())
    size = float(np.abs(np.concatenate([lo, hi])).max())
    hint = ""
    for unit, factor in (("cm", 100.0), ("mm", 1000.0)):
        if 0.3 * factor * size < reach < 3 * factor * size:
            hint = f": positions in {unit}? (rfir import csv --position-unit {unit})"
    raise InputFileError(f"{int(outside.sum())} of {len(pts)} antenna positions lie outside the geometry's extent "
                         f"{np.round(lo, 2).tolist()}..{np.round(hi, 2).tolist()} m (they reach {reach:.3g})"
                         f"{hint or ': measurements of another scene, or in another unit?'}",
                         path=where)


def _rows_clear_of_geometry(geom, meas, rows: np.ndarray, where: str, min_clearance_m: float, progress) -> np.ndarray:
    """The training rows whose two antennas lie outside the geometry; the others are left out with a
    warning that names them (a measured position against a desk or a wall), and a file whose every
    training antenna lies inside is refused (the geometry or the file is wrong)."""
    tx, rx = np.asarray(meas["tx_pos"])[rows], np.asarray(meas["rx_pos"])[rows]
    pts = np.concatenate([tx, rx])
    inside, nearest = positions_inside(geom, pts, min_clearance_m)
    if not inside.any():
        return rows
    bad_row = inside[:len(rows)] | inside[len(rows):]
    words = inside_words(pts, inside, nearest, min_clearance_m)
    if bad_row.all():
        raise InputFileError(words, path=where)
    progress.log(f"warning: {where}: {words}: their {int(bad_row.sum())} of {len(rows)} training links are "
                 "left out")
    return rows[~bad_row]
