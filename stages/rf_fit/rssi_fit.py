"""`rfir rf-fit` for RSSI measurements (task "rssi"): the physical room model (room_stage.py).

Called by stage.run when the measurement file's task is "rssi". Checks the request, picks the
training rows (`[rf_fit.rssi] split`, rssi_split.py), the frequency column and the training targets,
then fits the room model (docs/physics.md section 8.10, docs/rssi.md) and writes its `rf` artifact.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from rfir_cli.errors import ConfigError, InputFileError, StageError
from rfir_cli.progress import NullProgress

from .links import check_overlap, check_positions, geometry_from_artifact
from .rssi_split import rssi_settings, training_rows


def run_rssi(scene, meas, scene_path: Path, measurements_path: Path, out_path: Path, config: dict, render_cfg,
             fit_cfg=None, *, seed: int = 0, config_toml: str = "", progress=None):
    """Fit the room model to the RSSI links of `meas`; see the module docstring. config: the [rf_fit] table.
    fit_cfg (rf-fit's FitConfig) is not used: the room model's optimiser settings are [rf_fit.physical].
    Returns stage.RfFitResult."""
    from .room_stage import run_room

    progress = progress or NullProgress()
    t_start = time.time()
    cfg = rssi_settings(config)
    if str(config.get("split", "data")) != "data":
        raise ConfigError(f"rf_fit.split = {config['split']!r} is for rcs data; RSSI data uses rf_fit.rssi.split "
                          "('file' or 'holdout_tx')")
    kind = str(config.get("antenna", "auto"))
    if kind not in ("auto", "isotropic"):
        raise ConfigError(f"rf_fit.antenna = {kind!r}: the room model takes isotropic antennas")
    geom = geometry_from_artifact(scene)
    where = str(measurements_path)
    check_overlap(geom, meas, where)
    rows, held = training_rows(meas, cfg, seed, where)
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
    tx, rx = np.asarray(meas["tx_pos"])[rows], np.asarray(meas["rx_pos"])[rows]
    check_positions(geom, np.concatenate([tx, rx]), where, float(config.get("min_clearance_m", 0.02)))
    target_db = np.asarray(meas["path_gain_db"], np.float64)[rows, col]
    if not np.isfinite(target_db).all():
        raise InputFileError("path_gain_db has non-finite training values", path=measurements_path)
    return run_room(scene, meas, geom, rows, held, tx, rx, float(freqs[col]), target_db, scene_path,
                    measurements_path, out_path, config, render_cfg, cfg, seed=seed, config_toml=config_toml,
                    progress=progress, t_start=t_start)
