"""Rows for diagnose from a model and a measurement file.

MODEL is an `rf` artifact (its radio model, rfir_stages.model.radio_model, predicts the measured links at the
measured frequencies, with the effects diagnose recorded in it, as `rfir predict` does: a room model at every
measured frequency inside its material laws' range, a frequency outside refused in one line; an object model at
the measured ones it predicts by default (its fitted frequencies or band), or at the measured ones when it
predicts none of them by default; which frequencies were used, and why, is info["frequencies"]),
or a `predictions` artifact (any method's prediction of the same links), or a `measurements`
artifact used as a prediction (a plain ray tracer's output, e.g. Sionna without the effect).
Train/test: the rf fit's split as predict scores it; otherwise the measurement file's split column
(1 = test); otherwise a seeded 70/30 split of the links.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rfir_core.artifacts import read_artifact
from rfir_core.errors import ConfigError, InputFileError, StageError
from rfir_stages.model.antenna_patterns import link_axes
from rfir_stages.model.links import check_overlap, geometry_from_artifact
from rfir_stages.model.occlusion import make_provider
from rfir_stages.model.radio_model import load_model

from .apply import apply_recorded_effects
from .crossings import crossings_from_artifact
from .rows import Rows


def _match_links(model_links: np.ndarray, meas_links: np.ndarray, tol_m: float = 1e-4) -> np.ndarray | None:
    """Row of the model for each measured link [L] (Tx and Rx positions [L, 6] within tol_m), or None."""
    if model_links.shape != meas_links.shape:
        return None
    if np.allclose(model_links, meas_links, atol=tol_m):
        return np.arange(len(meas_links))
    from scipy.spatial import cKDTree

    dist, idx = cKDTree(model_links).query(meas_links)
    if np.any(dist > tol_m) or len(np.unique(idx)) != len(idx):
        return None
    return idx


def _columns(model_freqs: np.ndarray, meas_freqs: np.ndarray, where) -> np.ndarray:
    cols = [int(np.flatnonzero(np.abs(meas_freqs - f) <= 1e-6 * f)[0]) for f in model_freqs
            if np.any(np.abs(meas_freqs - f) <= 1e-6 * f)]
    if not cols:
        raise StageError("the model predicts none of the measured frequencies", path=where)
    return np.asarray(cols)


def load_rows(model_path, measurements_path, work_dir: Path, *, geometry_path=None, seed: int = 0,
              progress=None) -> tuple[Rows, dict]:
    """(Rows, info) for the model at model_path against measurements_path (module docstring)."""
    model_path, measurements_path = Path(model_path), Path(measurements_path)
    for p in (model_path, measurements_path):
        if not p.exists():
            raise InputFileError("no such file", path=p)
    meas = read_artifact(measurements_path, "measurements")
    task = "rssi" if str(meas.attrs.get("task", "")) == "rssi" else "rcs"
    model = read_artifact(model_path, ("rf", "predictions", "measurements"))
    kind = model.kind
    info = {"model": str(model_path), "model_kind": kind, "measurements": str(measurements_path), "task": task}
    split = None
    if kind == "rf":
        pred, split, info["frequencies"] = _predict_measured(model, meas, task, progress)   # the measured rows
        if geometry_path is None:
            geometry_path = model_path
    else:
        pred = model
    tx, rx = np.asarray(meas["tx_pos"], np.float64), np.asarray(meas["rx_pos"], np.float64)
    ptx, prx = np.asarray(pred["tx_pos"], np.float64), np.asarray(pred["rx_pos"], np.float64)
    order = _match_links(np.concatenate([ptx, prx], 1), np.concatenate([tx, rx], 1))
    if order is None:
        raise StageError(f"the model's links differ from the measured ones ({len(ptx)} vs {len(tx)} links, "
                         "or other positions); predict the measured links", path=model_path)
    f_meas = np.asarray(meas["freq_hz"], np.float64)
    f_model = np.asarray(pred["freq_hz"], np.float64)
    cols = _columns(f_model, f_meas, model_path)
    mcols = _columns(f_meas[cols], f_model, model_path)
    if "frequencies" not in info:
        info["frequencies"] = (", ".join(f"{f / 1e9:g}" for f in f_meas[cols][:4]) + (" ..." if len(cols) > 4 else "")
                               + f" GHz (the measured frequencies the {kind} artifact holds)")
    pred_db = np.asarray(pred["path_gain_db"], np.float64)[order][:, mcols]
    meas_db = np.asarray(meas["path_gain_db"], np.float64)[:, cols]
    if split is None and meas.get("split") is not None:
        split = np.asarray(meas["split"])
        info["split"] = "the measurement file's split column"
    elif split is not None:
        info["split"] = "the rf fit's split (as predict scores it)"
    if split is None or not (np.any(split == 1) and np.any(split == 0)):
        split = (np.random.default_rng(seed).random(len(tx)) < 0.3).astype(int)
        info["split"] = f"random 70/30 of the links, seed {seed}"
    n_l, n_f = meas_db.shape
    rep = lambda a: np.repeat(a, n_f, axis=0)   # noqa: E731  rows are link-major
    test = rep(split == 1)
    train = rep(split == 0)
    aspect = rep(np.asarray(meas["aspect_rad"], np.float64)) if meas.get("aspect_rad") is not None else None
    rng_m = rep(np.asarray(meas["range_m"], np.float64)) if meas.get("range_m") is not None else None
    good = np.isfinite(pred_db.reshape(-1)) & np.isfinite(meas_db.reshape(-1))
    channel = meas.get("channel")
    channel, info["phases"] = measured_phases(None if channel is None else np.asarray(channel)[:, cols].reshape(-1)[good],
                                              "the measurement file")
    pchannel = pred.get("channel") if kind == "measurements" else None
    pchannel, _ = measured_phases(None if pchannel is None else np.asarray(pchannel)[order][:, mcols].reshape(-1)[good],
                                  "the model")
    crossings = None
    incidence = None
    if geometry_path is not None and task == "rssi":
        crossings = rep(_crossings(Path(geometry_path), tx, rx))
        info["geometry"] = str(geometry_path)
    elif geometry_path is not None:
        incidence = rep(incidence_deg(read_artifact(geometry_path, ("scene", "rf")), tx))
        info["geometry"] = str(geometry_path)
    rows = Rows(pred_db.reshape(-1)[good], meas_db.reshape(-1)[good], train[good], test[good], rep(tx)[good],
                rep(rx)[good], np.tile(f_meas[cols], n_l)[good], task,
                None if aspect is None else aspect[good], None if rng_m is None else rng_m[good],
                None if crossings is None else crossings[good], channel, pchannel,
                None if incidence is None else incidence[good])
    info.update(num_rows=rows.num, num_train=int(rows.train.sum()), num_test=int(rows.test.sum()),
                num_links=int(n_l), num_freqs=int(n_f))
    if rows.test.sum() < 10 or rows.train.sum() < 10:
        raise StageError(f"too few rows to diagnose ({int(rows.train.sum())} train, {int(rows.test.sum())} test)",
                         path=measurements_path)
    return rows, info


def _predict_measured(rf, meas, task: str, progress) -> tuple[dict, np.ndarray | None, str]:
    """({tx_pos, rx_pos, freq_hz, path_gain_db [L, F] dB}, the fit's split [L] or None, the frequencies predicted
    and why, in words) of the measured links, predicted by the radio model of `rf` at the frequencies of
    prediction_frequencies (refused, one line, when it predicts another task's quantity, or a room model a
    frequency outside its material laws' range)."""
    radio = load_model(rf, quantity=task)
    tx, rx = np.asarray(meas["tx_pos"], np.float64), np.asarray(meas["rx_pos"], np.float64)
    check_overlap(radio.geometry, meas, str(meas.path))
    freqs, why = prediction_frequencies(radio, np.asarray(meas["freq_hz"], np.float64))
    if freqs.size == 0:
        raise StageError("the model predicts none of the measured frequencies", path=rf.path)
    if task == "rssi":   # one line naming the measurements, before any tracing
        try:
            radio.predictor.check_frequencies(freqs)
        except ConfigError as err:
            raise InputFileError(f"the measured {err}", path=meas.path) from None
    aspect, rng = meas.get("aspect_rad"), meas.get("range_m")
    # a room model weights each link about its antennas' axes where the measurements hold them (tx_axis / rx_axis)
    pg = radio.predict(tx, rx, freqs, progress=progress, axes=link_axes(meas, str(meas.path)) if task == "rssi" else None)
    pg = apply_recorded_effects(rf, pg, tx, rx, freqs, aspect_rad=aspect, range_m=rng)
    return {"tx_pos": tx, "rx_pos": rx, "freq_hz": freqs, "path_gain_db": pg}, radio.training_split(meas), why


def prediction_frequencies(radio, measured_hz: np.ndarray) -> tuple[np.ndarray, str]:
    """(frequencies [F] Hz the model `radio` (a RadioModel) predicts the measured links at, why in words), for the
    measured frequencies measured_hz [K] Hz.

    A room model ("rssi"): every measured one (its paths are evaluated at any frequency inside its material laws'
    range). An object model: the measured ones it predicts by default (fitted frequencies; a band fit's band), or,
    when that leaves none, every measured one (its materials follow their laws at any frequency)."""
    fitted = ", ".join(f"{f / 1e9:g}" for f in radio.fitted_freqs_hz[:4]) + (" ..." if radio.fitted_freqs_hz.size > 4 else "")
    covered = radio.default_freqs(measured_hz)
    if radio.task != "rssi" and covered.size:
        freqs = covered
    else:
        freqs = np.asarray(measured_hz, np.float64)
    shown = ", ".join(f"{f / 1e9:g}" for f in freqs[:4]) + (f" ... ({freqs.size})" if freqs.size > 4 else "")
    if all(np.any(np.abs(covered - f) <= 1e-6 * f) for f in freqs):
        return freqs, f"{shown} GHz (measured, and what the model was fitted at)"
    return freqs, f"{shown} GHz (the measurements' frequencies; the model was fitted at {fitted} GHz)"


def measured_phases(channel: np.ndarray | None, where: str) -> tuple[np.ndarray | None, str]:
    """(the complex channel [N], or None where phases are absent; a note saying which). Phases are absent
    when the file has no channel, when any row lacks one (NaN), or when every phase is exactly 0: an
    importer's placeholder, not a measurement (a measured phase is never 0 on every row)."""
    if channel is None:
        return None, f"absent: {where} has no complex channel"
    channel = np.asarray(channel)
    bad = int(np.sum(~np.isfinite(channel)))
    if bad:
        return None, f"absent: {where} lacks the phase on {bad} of {channel.size} rows"
    if channel.size and np.all(np.asarray(channel).imag == 0) and np.all(np.asarray(channel).real >= 0):
        return None, f"absent: every phase in {where} is 0 (placeholders, not measured)"
    return channel, "measured"


def _crossings(geometry_path: Path, tx: np.ndarray, rx: np.ndarray) -> np.ndarray:
    return crossings_from_artifact(read_artifact(geometry_path, ("scene", "rf")), tx, rx)


def incidence_deg(art, radar_m: np.ndarray, min_response: float = 0.3) -> np.ndarray:
    """Incidence angle [deg, L] on the dominant surface of a monostatic radar: the first Gaussian
    (response >= min_response) on the ray from each radar position toward the centre of the
    Gaussians, angle between its normal and the ray back to the radar; nan where the ray hits nothing."""
    import torch


    geom = geometry_from_artifact(art)
    centre = geom.means.mean(0)
    origins = torch.as_tensor(radar_m, dtype=torch.float64)
    dirs = centre[None] - origins
    dirs = dirs / dirs.norm(dim=-1, keepdim=True).clamp(min=1e-12)
    hits = make_provider("auto", geom).ray_hits(origins.contiguous(), dirs.contiguous())
    strong = hits.select(hits.response >= min_response)
    out = np.full(len(radar_m), np.nan)
    q = strong.query.numpy()
    first = np.unique(q, return_index=True)[1]          # hits are sorted front to back per query
    cos = (geom.normals[strong.gaussian[first]] * dirs[q[first]]).sum(-1).abs().clamp(max=1.0)
    out[q[first]] = np.degrees(np.arccos(cos.numpy()))
    return out
