"""`rfir predict rssi`: received power from a fitted room model (rf-fit on task "rssi" data; rfir_stages.model.room).

Two uses:
- map: `--tx X,Y,Z` with receivers from `--rx FILE` (CSV x,y,z in metres, header optional), a
  `--grid HEIGHT,STEP` over the scene's floor plan, or (with --measurements) the measured
  receivers of that transmitter; heatmap PNGs (predicted, and measured and error where measured).
- evaluation: `--measurements` without --tx: every row of the file; the test rows of the split the
  model was fitted with are scored beside the log-distance and multi-wall baselines fitted on the
  training rows (rssi_baselines.py) and written to a results JSON (default: the output with .json).
Both write a `predictions` artifact; `--plots` adds the FoV renders of |Gamma|, angle(Gamma), R.
Positions outside the scene's bounds or inside the geometry are warned about (named); a request
whose memory estimate exceeds `predict.rssi.max_memory_gb` is refused before any work.
"""
from __future__ import annotations

import csv
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rfir_cli.artifacts import read_artifact, write_artifact
from rfir_cli.errors import ConfigError, InputFileError, StageError
from rfir_cli.progress import NullProgress
from rfir_cli.provenance import Provenance

from . import rssi_baselines as bl
from .baselines import baselines_beating_model
from .heatmap import error_limits, fov_maps, radio_map
from .rssi_checks import check_points, floor_grid, grid_shape
from .rssi_model_io import load_predictor

if TYPE_CHECKING:
    from rfir_stages.model.room import RoomPredictor



def rssi_defaults() -> dict:
    """The [predict.rssi] table of configs/predict.toml (what a caller's config does not set)."""
    from rfir_cli.config import load_defaults

    return dict(load_defaults().get("predict", {}).get("rssi", {}))


@dataclass
class RssiPredictResult:
    """Summary of one `predict rssi` run; metrics: name -> value (MAE in dB on the test split)."""

    path: Path
    num_links: int
    freq_hz: float
    wall_time_s: float
    predict_time_s: float
    metrics: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    plots: list = field(default_factory=list)
    results_json: Path | None = None


def read_points_csv(path) -> np.ndarray:
    """Receiver positions [N, 3] m from a CSV with three numeric columns (x, y, z; one header line allowed)."""
    path = Path(path)
    try:
        with open(path, newline="") as handle:
            rows = [r for r in csv.reader(handle) if r and any(c.strip() for c in r)]
    except FileNotFoundError:
        raise InputFileError("receiver file not found", path=path) from None
    out = []
    for i, row in enumerate(rows):
        try:
            out.append([float(c) for c in row[:3]] if len(row) >= 3 else None)
        except ValueError:
            if i == 0:
                continue  # header
            raise InputFileError(f"line {i + 1}: expected three numbers x,y,z in metres, got {row}", path=path) from None
        if out[-1] is None:
            raise InputFileError(f"line {i + 1}: expected three columns x,y,z in metres", path=path)
    if not out:
        raise InputFileError("no receiver positions (expected lines x,y,z in metres)", path=path)
    pts = np.asarray(out, np.float64)
    if not np.isfinite(pts).all():
        raise InputFileError("receiver positions must be finite numbers", path=path)
    return pts


def _refuse_large(pred: RoomPredictor, num_points: int, cfg: dict) -> None:
    """Refuse, with the estimate, a request whose memory estimate is above predict.rssi.max_memory_gb."""
    need = pred.memory_estimate_bytes(num_points, int(cfg["chunk_links"]))
    if need > float(cfg["max_memory_gb"]) * 2**30:
        raise StageError(f"{num_points} points ({pred.geom.num} Gaussians) need about {need / 2**30:.1f} GiB, above "
                         f"predict.rssi.max_memory_gb = {cfg['max_memory_gb']:g}; use a coarser --grid STEP or fewer --rx")


def _test_train_rows(rf, meas) -> tuple[np.ndarray, np.ndarray, str]:
    attrs = rf.free.get("training@attrs", {})
    protocol = str(attrs.get("split", "file"))
    if protocol == "holdout_tx":
        held = np.asarray(rf.free.get("training", {}).get("holdout_tx_ids", []), np.int64)
        tx_id = meas.get("tx_id")
        if tx_id is None or held.size == 0:
            raise StageError("the model held transmitters out, but the measurements have no tx_id", path=meas.path)
        test = np.isin(np.asarray(tx_id), held)
        return np.flatnonzero(test), np.flatnonzero(~test), f"transmitters {held.tolist()} held out"
    split = meas.get("split")
    if split is None:
        raise StageError("the measurements have no 'split' to score against", path=meas.path)
    split = np.asarray(split)
    return np.flatnonzero(split == 1), np.flatnonzero(split == 0), "the file's split column (test rows: split == 1)"


def _baselines(pred, rf, geom_labels, provider, tx, rx, y, train, test) -> dict:
    d = np.linalg.norm(rx - tx, axis=1)
    out = {}
    ld = bl.fit_log_distance(d[train], y[train])
    out["baseline_log_distance_mae_db"] = float(np.mean(np.abs(bl.predict_log_distance(ld, d[test]) - y[test])))
    out["baseline_log_distance_mae_train_db"] = float(np.mean(np.abs(bl.predict_log_distance(ld, d[train]) - y[train])))
    out["baseline_log_distance_params"] = ld
    names = rf.attrs.get("label_names")
    counts, classes = bl.crossing_counts(provider, geom_labels, None if names is None else list(names), tx, rx)
    mw = bl.fit_multiwall(d[train], counts[train], y[train], classes)
    out["baseline_multiwall_mae_db"] = float(np.mean(np.abs(bl.predict_multiwall(mw, d[test], counts[test], classes)
                                                             - y[test])))
    out["baseline_multiwall_mae_train_db"] = float(np.mean(np.abs(
        bl.predict_multiwall(mw, d[train], counts[train], classes) - y[train])))
    out["baseline_multiwall_params"] = mw
    out["test_links_crossing_objects"] = int((counts[test].sum(1) > 0).sum())
    out["baseline_nearest_links_mae_db"] = float(np.mean(np.abs(bl.nearest_links(tx, rx, y, train, test) - y[test])))
    return out


def run_rssi(rf_path, out_path, config: dict, *, tx=None, rx_file=None, grid=None, measurements_path=None,
             plots_dir=None, results_path=None, name: str | None = None, seed: int = 0, config_toml: str = "",
             progress=None) -> RssiPredictResult:
    """Predict RSSI; see the module docstring. config: the [predict] table (its `rssi` sub-table)."""
    progress = progress or NullProgress()
    t_start = time.time()
    cfg = {**rssi_defaults(), **(config.get("rssi", {}) or {})}
    rf_path, out_path = Path(rf_path), Path(out_path)
    for p in (rf_path, measurements_path):
        if p is not None and out_path.resolve() == Path(p).resolve():
            raise ConfigError(f"-o {out_path} would overwrite the input {p}")
    if rx_file is not None and grid is not None:
        raise ConfigError("give either --rx or --grid, not both")
    if tx is None and measurements_path is None:
        raise ConfigError("give --tx X,Y,Z (a map), or --measurements FILE (score the model on its test split)")
    rf = read_artifact(rf_path, "rf")
    pred = load_predictor(rf, str(config.get("occlusion", "auto")))
    meas = read_artifact(measurements_path, "measurements") if measurements_path is not None else None
    if meas is not None and str(meas.attrs.get("task", "")) != "rssi":
        raise StageError("`predict rssi` needs task 'rssi' measurements", path=measurements_path)
    bounds = pred.geom.means.min(0).values.numpy(), pred.geom.means.max(0).values.numpy()

    measured = split = None
    if tx is not None:
        tx = np.asarray(tx, np.float64).reshape(3)
        if rx_file is not None:
            rx = read_points_csv(rx_file)
        elif grid is not None or meas is None:
            height, step = grid if grid is not None else cfg["grid"]
            _refuse_large(pred, int(np.prod(grid_shape(bounds, step))), cfg)
            rx = floor_grid(bounds, height, step)
        else:
            rows = np.flatnonzero(np.linalg.norm(np.asarray(meas["tx_pos"]) - tx, axis=1) < cfg["tx_match_m"])
            if rows.size == 0:
                raise StageError(f"no measured transmitter at {tx.tolist()} m; give --grid or --rx", path=measurements_path)
            rx = np.asarray(meas["rx_pos"])[rows]
            measured = np.asarray(meas["path_gain_db"], np.float64)[rows, 0]
        txs = np.broadcast_to(tx, rx.shape).copy()
    else:
        txs, rx = np.asarray(meas["tx_pos"], np.float64), np.asarray(meas["rx_pos"], np.float64)
        measured = np.asarray(meas["path_gain_db"], np.float64)[:, 0]
    _refuse_large(pred, len(rx), cfg)
    warnings = check_points(pred.geom, txs, "transmitter", bounds, provider=pred.provider)
    warnings += check_points(pred.geom, rx, "receiver", bounds, provider=pred.provider)   # the CLI prints them

    t0 = time.time()
    with progress.task("predict rssi", total=len(rx)) as bar:
        pg = pred.path_gain_db(txs, rx, int(cfg["chunk_links"]), bar)
    from rfir_stages.diagnose.apply import apply_recorded_effects   # effects named by `rfir diagnose`

    pg = apply_recorded_effects(rf, pg[:, None], txs, rx, np.asarray([pred.freq_hz]))[:, 0]
    predict_s = time.time() - t0

    metrics, test = {}, None
    if tx is None:
        test, train, protocol = _test_train_rows(rf, meas)
        split = np.zeros(len(rx), np.int64)
        split[test] = 1
        metrics = {"split": protocol, "num_test": int(test.size), "num_train": int(train.size),
                   "mae_db": float(np.mean(np.abs(pg[test] - measured[test]))),
                   "mae_train_db": float(np.mean(np.abs(pg[train] - measured[train])))}
        labels = rf.get("gaussians/labels")
        metrics.update(_baselines(pg, rf, labels, pred.provider, txs, rx, measured, train, test))
        warnings += baselines_beating_model(metrics)   # printed and in the results JSON
        warnings += baselines_beating_model({"mae_db": metrics["mae_train_db"], **{
            k.replace("_mae_train_db", "_mae_db"): v for k, v in metrics.items() if k.endswith("_mae_train_db")}},
            rows="training")
    elif measured is not None:
        metrics = {"mae_db_this_tx": float(np.mean(np.abs(pg - measured))), "num_points": int(len(rx))}

    data = {"tx_pos": txs, "rx_pos": rx, "freq_hz": np.asarray([pred.freq_hz]), "path_gain_db": pg[:, None]}
    if measured is not None:
        data["measured_db"] = measured[:, None]
    if split is not None:
        data["split"] = split
    prov = Provenance(stage="predict.rssi", config_toml=config_toml)
    prov.add_input(rf_path)
    if measurements_path is not None:
        prov.add_input(measurements_path)
    prov.wall_time_s = time.time() - t_start
    prov.extra = {"predict_time_s": predict_s, "seed": seed, "warnings": "; ".join(warnings)}
    flat = {k: v for k, v in metrics.items() if isinstance(v, (int, float, str))}
    write_artifact(out_path, "predictions", data, attrs={"task": "rssi", "quantity": "path_gain_db"}, provenance=prov,
                   free={"metrics": {"@attrs": flat}} if flat else None)
    result = RssiPredictResult(out_path, len(rx), pred.freq_hz, time.time() - t_start, predict_s, metrics, warnings)
    if plots_dir is not None:
        result.plots = _plots(Path(plots_dir), pred, rf, meas, txs, rx, pg, measured, test)
    if results_path is not None and metrics:
        result.results_json = _results(Path(results_path), name or out_path.stem, rf, rf_path, measurements_path,
                                       result, seed)
    return result


def _plots(folder: Path, pred: RoomPredictor, rf, meas, txs, rx, pg, measured, test) -> list:
    means = pred.geom.means.numpy()
    z_lo, z_hi = means[:, 2].min(), means[:, 2].max()
    floor = means[(means[:, 2] > z_lo + 0.05) & (means[:, 2] < z_hi - 0.05), :2]   # walls and objects
    if test is not None:  # evaluation: the maps of the transmitter with the most test links
        tx_all = np.asarray(meas["tx_pos"])
        uniq, inv = np.unique(np.round(tx_all, 6), axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        best = np.bincount(inv[test], minlength=len(uniq)).argmax()
        sel = np.flatnonzero(inv == best)
    else:
        sel = np.arange(len(rx))
    tx = txs[sel[0]]
    where = f"Tx ({', '.join(f'{x:.2f}' for x in tx)}) m, {pred.freq_hz / 1e9:g} GHz"
    lo = float(np.nanmin(pg[sel] if measured is None else np.concatenate([pg[sel], measured[sel]])))
    hi = float(np.nanmax(pg[sel] if measured is None else np.concatenate([pg[sel], measured[sel]])))
    paths = [radio_map(folder / "rssi_predicted.png", rx[sel], pg[sel], tx, floor, f"predicted path gain, {where}",
                       "path gain [dB]", vmin=lo, vmax=hi)]
    if measured is not None:
        err = pg[sel] - measured[sel]
        paths.append(radio_map(folder / "rssi_measured.png", rx[sel], measured[sel], tx, floor,
                               f"measured path gain, {where}", "path gain [dB]", vmin=lo, vmax=hi))
        e_lo, e_hi = error_limits(err)
        paths.append(radio_map(folder / "rssi_error.png", rx[sel], err, tx, floor,
                               f"error (predicted - measured), {where}; MAE {np.mean(np.abs(err)):.2f} dB",
                               "error [dB]", cmap="RdBu_r", vmin=e_lo, vmax=e_hi))
    paths.append(fov_maps(folder / "fov_attributes.png", pred.geom, rf, tx))
    return paths


def _plain(value):
    """An attribute as JSON can hold it (arrays as lists, numpy scalars as numbers)."""
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value.item() if hasattr(value, "item") else value


def _results(path: Path, name, rf, rf_path, measurements_path, result: RssiPredictResult, seed) -> Path:
    training = rf.free.get("training@attrs", {})
    model = rf.free.get("model@attrs", {})
    doc = {"name": name, "task": "rssi", "scene": str(rf.attrs.get("scene", "")), "freq_hz": result.freq_hz,
           "rf": str(rf_path), "measurements": str(measurements_path), "seed": seed,
           "num_gaussians": int(len(rf["rf/opacity"])), "metrics": result.metrics,
           "model": {k: _plain(v) for k, v in model.items()},
           "fit": {k: _plain(v) for k, v in training.items()},
           "predict_wall_time_s": result.wall_time_s, "predict_time_s": result.predict_time_s,
           "num_links": result.num_links, "warnings": result.warnings}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(json.dumps(doc, indent=2, default=str) + "\n")
    tmp.replace(path)
    return path
