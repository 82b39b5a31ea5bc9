"""rfir from Python: what the CLI does, as functions on files and arrays (docs/guide/python-api.md).

    from rfir_stages import api
    model = api.fit("scene.h5", "survey.h5", "rf.h5")          # rf-fit: materials of the Gaussians
    grid = api.predict_map(model, tx_m=[1.2, 2.0, 1.8], height_m=1.0, step_m=0.5)
    edited = api.edit(model, "rf_edited.h5", ("label:partition", "delete"))

Units everywhere: positions in metres, frequencies in hertz, path gain 10 log10(P_r / P_t) in dB (received
power in dBm = transmit power in dBm + path gain), RCS in dBsm. The artifacts are the CLI's: a model fitted here
is predicted by `rfir predict` and the other way round. Functions raise rfir_core.errors.RfirError subclasses
with one line naming the file or option, as the CLI prints them.

Every prediction goes through the model's one interface (rfir_stages.model.radio_model.RadioModel), whatever its
kind (the object RCS model or the room model), with the corrections `rfir diagnose` recorded applied on top, as
`rfir predict` applies them.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rfir_core.artifacts import Artifact, read_artifact
from rfir_core.config import resolve_config, to_toml
from rfir_core.physics.closed_forms import rcs_from_path_gain
from rfir_stages.diagnose.apply import apply_recorded_effects
from rfir_stages.edit.script import edits_from_options, read_script
from rfir_stages.edit.stage import run as run_edit
from rfir_stages.model.antenna_patterns import antenna_from_attrs
from rfir_stages.model.links import radar_links, scene_centre
from rfir_stages.model.radio_model import RadioModel, link_positions, load_model
from rfir_stages.predict.rssi_checks import floor_grid, grid_shape
from rfir_stages.rf_fit.stage import run as run_rf_fit

__all__ = ["RadioMap", "RadioModel", "edit", "fit", "load_measurements", "load_model", "load_scene", "predict",
           "predict_map", "predict_rcs", "save"]


def load_scene(path) -> Artifact:
    """A `scene` artifact (Gaussians from `rfir geom` or `rfir mesh-gaussians`; an `rf` artifact holds them too):
    data["gaussians/means"] [G, 3] m, "gaussians/log_scales" [G, 3] (log m), "gaussians/rotations" [G, 4]
    (quaternions w, x, y, z), "gaussians/normals" [G, 3], "gaussians/labels" [G] with attrs["label_names"]."""
    return read_artifact(Path(path), ("scene", "rf"))


def load_measurements(path) -> Artifact:
    """A `measurements` artifact (`rfir import csv` or `rfir simulate`): data["tx_pos"], ["rx_pos"] [L, 3] m,
    ["freq_hz"] [F] Hz, ["path_gain_db"] [L, F] dB, ["split"] [L] (0 training, 1 test) where present; attrs["task"]
    is "rcs", "wideband" or "rssi"."""
    return read_artifact(Path(path), "measurements")


def _path(source) -> Path:
    """The file of a path or of an artifact read from one."""
    return Path(source.path) if isinstance(source, Artifact) else Path(source)


def fit(scene, measurements, out_path, *, settings: list[str] | tuple = (), config_file=None, recipe: str | None = None,
        seed: int = 0, progress=None) -> RadioModel:
    """Fit the radio materials of a scene's Gaussians to measurements (`rfir rf-fit`) and load the model written at
    out_path (an `rf` artifact). scene, measurements: paths (or artifacts read from them); settings: overrides in the
    CLI's --set form ("rf_fit.physical.iterations=200"); config_file, recipe: as --config and --recipe; progress: an
    rfir_core.progress.Progress (default: silent). The fit's figures are in
    model.artifact.free["training@attrs"] (train_mae_db, initial_mae_db, ...)."""
    config = resolve_config(config_file, list(settings), recipe)
    run_rf_fit(_path(scene), _path(measurements), Path(out_path), dict(config.get("rf_fit", {})), seed=seed,
               config_toml=to_toml(config), progress=progress)
    return load_model(Path(out_path))


def predict(model: RadioModel, tx_m, rx_m, freqs_hz=None, *, aspect_rad=None, range_m=None,
            progress=None) -> np.ndarray:
    """Path gain [N, F] dB of the links tx_m -> rx_m ([N, 3] m, or one position [3] for all) at freqs_hz [F] Hz
    (default: the model's own), with the corrections
    `rfir diagnose` recorded in the model; aspect_rad, range_m [N]: turntable coordinates of monostatic links, which
    some of those corrections use."""
    tx, rx = link_positions(tx_m, rx_m)
    freqs = model.default_freqs() if freqs_hz is None else np.atleast_1d(np.asarray(freqs_hz, np.float64))
    pg = model.predict(tx, rx, freqs, progress=progress)
    return apply_recorded_effects(model.artifact, pg, tx, rx, freqs, aspect_rad=aspect_rad, range_m=range_m)


@dataclass
class RadioMap:
    """Path gain on a horizontal grid: x_m [NX], y_m [NY] cell centres, height_m, path_gain_db [NX, NY, F] dB
    (NaN within min_distance_m of the transmitter, where no far-field path gain exists), freqs_hz [F]."""

    x_m: np.ndarray
    y_m: np.ndarray
    height_m: float
    path_gain_db: np.ndarray
    freqs_hz: np.ndarray

    def received_power_dbm(self, tx_power_dbm: float) -> np.ndarray:
        """Received power [NX, NY, F] dBm for a transmit power in dBm."""
        return self.path_gain_db + float(tx_power_dbm)


def predict_map(model: RadioModel, tx_m, *, height_m: float = 1.0, step_m: float = 0.5, freqs_hz=None,
                min_distance_m: float = 0.2, progress=None) -> RadioMap:
    """The radio map of one transmitter tx_m [3] m: receivers on a grid of step_m cells at height_m over the
    scene's x-y extent (as `rfir predict rssi --tx X,Y,Z --grid HEIGHT,STEP`)."""
    means = model.geometry.means.numpy()
    bounds = means.min(0), means.max(0)
    nx, ny = grid_shape(bounds, step_m)
    rx = floor_grid(bounds, height_m, step_m)                      # x-major: [NX * NY, 3]
    tx = np.asarray(tx_m, np.float64).reshape(3)
    freqs = model.default_freqs() if freqs_hz is None else np.atleast_1d(np.asarray(freqs_hz, np.float64))
    far = np.linalg.norm(rx - tx, axis=1) >= min_distance_m
    values = np.full((len(rx), len(freqs)), np.nan)
    if far.any():
        values[far] = predict(model, np.broadcast_to(tx, rx[far].shape), rx[far], freqs, progress=progress)
    return RadioMap(rx[::ny, 0].copy(), rx[:ny, 1].copy(), float(height_m), values.reshape(nx, ny, len(freqs)), freqs)


def predict_rcs(model: RadioModel, aspects_deg, ranges_m, freqs_hz=None, *, separation_m: float = 0.002,
                progress=None) -> np.ndarray:
    """Monostatic RCS [R, A, F] dBsm of the model's object at aspects_deg [A] deg, ranges_m [R] m and freqs_hz [F] Hz
    (default: the model's own), the radar in simulate's turntable convention (as `rfir predict rcs --aspects
    --ranges --freqs`)."""
    aspects = np.radians(np.atleast_1d(np.asarray(aspects_deg, np.float64)))
    ranges = np.atleast_1d(np.asarray(ranges_m, np.float64))
    freqs = model.default_freqs() if freqs_hz is None else np.atleast_1d(np.asarray(freqs_hz, np.float64))
    tx, rx, asp, rng = radar_links(aspects, ranges, scene_centre(model.geometry).numpy(), separation_m)
    pg = predict(model, tx, rx, freqs, aspect_rad=asp, range_m=rng, progress=progress)
    g0 = antenna_from_attrs(model.artifact.free.get("model@attrs", {})).boresight_gain
    rcs = 10 * np.log10(rcs_from_path_gain(10 ** (pg / 10), rng[:, None], freqs[None], g0, g0))
    return rcs.reshape(len(ranges), len(aspects), len(freqs))


def edit(model: RadioModel, out_path, *edits: tuple[str, str], script=None, allow_empty: bool = False) -> RadioModel:
    """Apply edits to the model's Gaussians (`rfir edit`) and load the edited model written at out_path. Each edit
    is (selection, operation) in the CLI's words, e.g. ("label:partition", "delete"), ("label:table_*",
    "translate:0.5,0,0"), ("box:0,0,0:1,1,2", "material:concrete"); or script: a TOML edit script. The model must
    have been read from a file (model.path; `save` it first otherwise)."""
    if model.path is None:
        raise ValueError("the model has no file: save it first (api.save), then edit")
    parsed = read_script(script, allow_empty) if script is not None else []
    parsed += edits_from_options([s for s, _ in edits], [o for _, o in edits], allow_empty) if edits else []
    run_edit(model.path, Path(out_path), parsed, allow_empty=allow_empty)
    return load_model(Path(out_path))


def save(model: RadioModel, path) -> Path:
    """Write the model as an `rf` artifact at path (never over the file it was read from); returns the path."""
    return model.save(path)
