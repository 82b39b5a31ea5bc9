"""`rfir predict rssi`: received power from a fitted room model (rf-fit on task "rssi" data; rfir_stages.model.room).

Two uses:
- map: `--tx X,Y,Z` with receivers from `--rx FILE` (CSV x,y,z in metres, header optional), a
  `--grid HEIGHT,STEP` over the scene's floor plan, or (with --measurements) the measured
  receivers of that transmitter; heatmap PNGs (predicted, and measured and error where measured).
- evaluation: `--measurements` without --tx: every row of the file; the test rows of the split the
  model was fitted with are scored beside the log-distance and multi-wall baselines fitted on the
  training rows (rssi_baselines.py) and written to a results JSON (default: the output with .json).
Both write a `predictions` artifact; `--plots` adds the FoV renders of |Gamma|, angle(Gamma), R.
Maps may be for several transmitters (a map each, the best server, the coverage above a threshold), in
received power [dBm] with a transmit power, and written as CSV / NPZ / TIFF beside the artifact
(rssi_maps.py); receivers closer than `predict.rssi.min_tx_distance_m` to a transmitter are left out
of its map. Positions outside the scene's bounds or inside the geometry are warned about (named); a
request whose memory estimate (memory_estimate_bytes) exceeds `predict.rssi.max_memory_gb` is refused
before any work, and receivers are checked and evaluated in blocks. No output replaces an input.
"""
from __future__ import annotations

import csv
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rfir_core.artifacts import check_output, read_artifact, write_artifact
from rfir_core.errors import ConfigError, InputFileError, StageError
from rfir_core.progress import NullProgress
from rfir_core.provenance import Provenance
from rfir_stages.diagnose.apply import apply_recorded_effects
from rfir_stages.model.antenna_patterns import RoomAntennas, link_axes
from rfir_stages.model.crossings import crossing_counts
from rfir_stages.model.radio_model import load_model

from . import rssi_baselines as bl
from . import rssi_maps
from .baselines import baselines_beating_model
from .heatmap import error_limits, fov_maps, radio_map
from .rssi_checks import check_points, floor_grid, grid_shape

if TYPE_CHECKING:
    from rfir_stages.model.radio_model import RadioModel



def rssi_defaults() -> dict:
    """The [predict.rssi] table of configs/predict.toml (what a caller's config does not set)."""
    from rfir_core.config import load_defaults

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
    # maps (--tx): transmitters [T, 3] m, receivers per map, unit of the map values ("dB" path gain or "dBm"),
    # per map {median, min, max, left_out} and the map files written (rssi_maps)
    num_tx: int = 0
    tx_m: np.ndarray | None = None
    map_points: int = 0
    unit: str = "dB"
    map_stats: list = field(default_factory=list)
    map_files: list = field(default_factory=list)
    # every frequency predicted [Hz] (the artifact's columns; freq_hz, the first, is the one scored and mapped) and
    # whether they were the model's fitted frequency, taken because none was asked for (freqs_hz None)
    freqs_hz: list = field(default_factory=list)
    freq_assumed: bool = False


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


# Memory of a map request, measured as the peak resident memory of `rfir predict rssi --grid` (with plots and
# every map file) on the reduced test room: 0.56, 0.78, 0.96 and 1.22 GB at 1.2k, 13k, 53k and 120k points.
# Fixed: the program itself (about 0.3 GB) and a block's tracing. Per point: the surfaces crossed from it to each
# diffuse cell, kept for later transmitters (room_diffuse.CellCrossings: 2 kB a point on that room, at most
# CROSSING_CACHE_BYTES in all), and about BYTES_PER_POINT for the positions, values, checks, files and plots;
# blocks of POINTS_PER_BLOCK receivers are checked and evaluated at a time, so the tracing's memory does not
# grow with the map.
BYTES_PER_POINT = 2_500
CROSSING_CACHE_BYTES = 256e6
FIXED_BYTES = 640 * 2**20
POINTS_PER_BLOCK = 8192


def memory_estimate_bytes(model: RadioModel, num_points: int, chunk_links: int) -> int:
    """Estimated peak memory [bytes] of predicting num_points links (see BYTES_PER_POINT)."""
    block = model.memory_estimate_bytes(min(num_points, POINTS_PER_BLOCK), chunk_links)
    return int(FIXED_BYTES + block + CROSSING_CACHE_BYTES + num_points * BYTES_PER_POINT)


def _refuse_large(model: RadioModel, num_points: int, cfg: dict) -> None:
    """Refuse, with the estimate (memory_estimate_bytes), a request above predict.rssi.max_memory_gb."""
    need = memory_estimate_bytes(model, num_points, int(cfg["chunk_links"]))
    if need > float(cfg["max_memory_gb"]) * 2**30:
        raise StageError(f"{num_points} points ({model.geometry.num} Gaussians) need about {need / 2**30:.1f} GiB, "
                         f"above predict.rssi.max_memory_gb = {cfg['max_memory_gb']:g}; use a coarser --grid STEP or fewer --rx")


def _path_gain_blocks(model: RadioModel, txs: np.ndarray, rx: np.ndarray, freqs: np.ndarray, chunk_links: int,
                      bar, axes=None) -> np.ndarray:
    """Predicted path gain [N, F] dB of links txs / rx [N, 3] m at freqs [F] Hz, POINTS_PER_BLOCK links at a time,
    with the effects `rfir diagnose` recorded; axes: the links' antenna axes (LinkAxes [N]; None: each end's own)."""
    out = np.empty((len(rx), len(freqs)))
    for lo in range(0, len(rx), POINTS_PER_BLOCK):
        hi = min(len(rx), lo + POINTS_PER_BLOCK)
        pg = model.predict(txs[lo:hi], rx[lo:hi], freqs, chunk_links=chunk_links, advance=bar.advance,
                           axes=None if axes is None else axes.rows(slice(lo, hi)))
        out[lo:hi] = apply_recorded_effects(model.artifact, pg, txs[lo:hi], rx[lo:hi], freqs)
    return out


def link_axes_for(model: RadioModel, meas, where) -> tuple:
    """(the antenna axes per link of the measurements `meas` the model predicts (LinkAxes; None: none, or a map),
    warnings [str]): a model whose antennas were oriented per link predicts links without axes (a map, a file
    without tx_axis / rx_axis) about each end's stated axis, which a warning says."""
    axes = None if meas is None else link_axes(meas, str(where))
    predictor = getattr(model, "predictor", None)          # the room model's (the kind predict rssi loads)
    antennas = RoomAntennas() if predictor is None else predictor.room.antennas
    missing = [s for s in antennas.per_link if axes is None or s not in axes.sides]
    if not missing:
        return axes, []
    ends = ", ".join(f"{s} {getattr(antennas, s).text()}" for s in missing)
    return axes, [f"the model's antennas were oriented per link ({', '.join(missing)}); these links state no "
                  f"{'/'.join(f'{s}_axis' for s in missing)}: predicted about the stated axis ({ends})"]


def _near_tx(rx: np.ndarray, tx: np.ndarray, min_m: float) -> np.ndarray:
    """[N] bool: receivers rx [N, 3] m closer than min_m to the transmitter tx [3] m."""
    return np.linalg.norm(rx - tx, axis=1) < min_m


def _baselines(pred, rf, geom_labels, provider, tx, rx, y, train, test) -> dict:
    d = np.linalg.norm(rx - tx, axis=1)
    out = {}
    ld = bl.fit_log_distance(d[train], y[train])
    out["baseline_log_distance_mae_db"] = float(np.mean(np.abs(bl.predict_log_distance(ld, d[test]) - y[test])))
    out["baseline_log_distance_mae_train_db"] = float(np.mean(np.abs(bl.predict_log_distance(ld, d[train]) - y[train])))
    out["baseline_log_distance_params"] = ld
    names = rf.attrs.get("label_names")
    counts, classes = crossing_counts(provider, geom_labels, None if names is None else list(names), tx, rx)
    mw = bl.fit_multiwall(d[train], counts[train], y[train], classes)
    out["baseline_multiwall_mae_db"] = float(np.mean(np.abs(bl.predict_multiwall(mw, d[test], counts[test], classes)
                                                             - y[test])))
    out["baseline_multiwall_mae_train_db"] = float(np.mean(np.abs(
        bl.predict_multiwall(mw, d[train], counts[train], classes) - y[train])))
    out["baseline_multiwall_params"] = mw
    out["test_links_crossing_objects"] = int((counts[test].sum(1) > 0).sum())
    out["baseline_nearest_links_mae_db"] = float(np.mean(np.abs(bl.nearest_links(tx, rx, y, train, test) - y[test])))
    return out


def _tx_array(tx) -> np.ndarray | None:
    """tx: None, one position [3] m or several [T, 3] -> [T, 3] float64 (None stays None)."""
    if tx is None:
        return None
    t = np.asarray(tx, np.float64)
    if t.size == 0 or t.size % 3:
        raise ConfigError(f"--tx: expected X,Y,Z in metres, got {np.asarray(tx).tolist()}")
    t = t.reshape(-1, 3)
    if not np.isfinite(t).all():
        raise ConfigError("--tx: positions must be finite numbers")
    return t


def output_files(out_path, *, plots_dir=None, results_path=None, formats=(), num_tx: int = 1) -> list[Path]:
    """Every file besides the artifact that a map request may write (to check before any work)."""
    files = [Path(results_path)] if results_path is not None else []
    files += [p for ps in rssi_maps.map_paths(Path(out_path), list(formats), num_tx).values() for p in ps]
    if plots_dir is not None:
        d = Path(plots_dir)
        names = ["rssi_predicted.png", "rssi_measured.png", "rssi_error.png", "fov_attributes.png", "coverage.png",
                 "best_tx.png"] + [f"rssi_predicted_tx{i + 1}.png" for i in range(num_tx)]
        files += [d / n for n in names]
    return files


def run_rssi(rf_path, out_path, config: dict, *, tx=None, rx_file=None, grid=None, measurements_path=None,
             plots_dir=None, results_path=None, name: str | None = None, seed: int = 0, config_toml: str = "",
             progress=None, tx_power_dbm: float | None = None, formats=(), threshold_dbm: float | None = None,
             freqs_hz=None) -> RssiPredictResult:
    """Predict RSSI; see the module docstring. config: the [predict] table (its `rssi` sub-table).

    tx: one transmitter position [3] m or several [T, 3] (one map each, plus the best server and, with
    threshold_dbm, the coverage); tx_power_dbm: transmit power [dBm]: maps and map files in received power
    [dBm] (the artifact keeps path gain [dB]); formats: map files beside the artifact ("csv", "npz",
    "tif"; rssi_maps); threshold_dbm: coverage threshold [dBm] (needs tx_power_dbm). Receivers closer than
    predict.rssi.min_tx_distance_m to a transmitter are left out of its map (NaN in the map files; not in
    the artifact) and counted in a warning. freqs_hz [F] Hz: the frequencies predicted (the artifact holds a column
    each, and measured_db only with one; the first is scored, mapped and plotted); None: the one the model was
    fitted at."""
    progress = progress or NullProgress()
    t_start = time.time()
    cfg = {**rssi_defaults(), **(config.get("rssi", {}) or {})}
    rf_path, out_path = Path(rf_path), Path(out_path)
    for p in (rf_path, measurements_path):
        if p is not None and out_path.resolve() == Path(p).resolve():
            raise ConfigError(f"-o {out_path} would overwrite the input {p}")
    if rx_file is not None and grid is not None:
        raise ConfigError("give either --rx or --grid, not both")
    txs_map = _tx_array(tx)
    if txs_map is None and measurements_path is None:
        raise ConfigError("give --tx X,Y,Z (a map), or --measurements FILE (score the model on its test split)")
    formats = rssi_maps.parse_formats(formats)
    if txs_map is None and (formats or threshold_dbm is not None or tx_power_dbm is not None):
        raise ConfigError("--format, --tx-power-dbm and --threshold-dbm are for maps: give --tx X,Y,Z")
    if threshold_dbm is not None and tx_power_dbm is None:
        raise ConfigError("--threshold-dbm needs --tx-power-dbm (the transmit power that turns path gain into dBm)")
    for value, what in ((tx_power_dbm, "--tx-power-dbm"), (threshold_dbm, "--threshold-dbm")):
        if value is not None and not np.isfinite(value):
            raise ConfigError(f"{what} must be a finite number, got {value}")
    several = txs_map is not None and len(txs_map) > 1
    if several and measurements_path is not None and rx_file is None and grid is None:
        raise ConfigError("several --tx share one set of receivers: give --grid HEIGHT,STEP or --rx FILE")
    if "tif" in formats and rx_file is not None:
        raise ConfigError("--format tif needs receivers on a grid (--grid), not --rx points")
    inputs = [rf_path, measurements_path, rx_file]
    check_output(out_path, "predictions", inputs=inputs)   # before any work
    for f in output_files(out_path, plots_dir=plots_dir, results_path=results_path, formats=formats,
                          num_tx=0 if txs_map is None else len(txs_map)):
        check_output(f, None, inputs=inputs)
    rf = read_artifact(rf_path, "rf")
    model = load_model(rf, quantity="rssi", occlusion=str(config.get("occlusion", "auto")))
    freqs = model.default_freqs()[:1] if freqs_hz is None else np.atleast_1d(np.asarray(freqs_hz, np.float64))
    freq_hz = float(freqs[0])
    meas = read_artifact(measurements_path, "measurements") if measurements_path is not None else None
    if meas is not None and str(meas.attrs.get("task", "")) != "rssi":
        raise StageError("`predict rssi` needs task 'rssi' measurements", path=measurements_path)
    bounds = model.geometry.means.min(0).values.numpy(), model.geometry.means.max(0).values.numpy()

    measured = split = grid_info = None
    warnings: list[str] = []
    if meas is not None and abs(float(np.asarray(meas["freq_hz"])[0]) - freq_hz) > 1e-6 * freq_hz:
        warnings.append(f"the measurements are at {float(np.asarray(meas['freq_hz'])[0]) / 1e9:g} GHz, scored against "
                        f"the prediction at {freq_hz / 1e9:g} GHz (--freqs sets the frequencies predicted)")
    if txs_map is not None:
        if rx_file is not None:
            rx = read_points_csv(rx_file)
        elif grid is not None or meas is None or several:
            height, step = grid if grid is not None else cfg["grid"]
            nx, ny = grid_shape(bounds, step)
            _refuse_large(model, nx * ny * len(txs_map), cfg)
            rx = floor_grid(bounds, height, step)
            grid_info = rssi_maps.GridInfo(nx, ny, (float(rx[0, 0]), float(rx[0, 1])), float(step), float(height))
        else:
            rows = np.flatnonzero(np.linalg.norm(np.asarray(meas["tx_pos"]) - txs_map[0], axis=1) < cfg["tx_match_m"])
            if rows.size == 0:
                raise StageError(f"no measured transmitter at {txs_map[0].tolist()} m; give --grid or --rx",
                                 path=measurements_path)
            rx = np.asarray(meas["rx_pos"])[rows]
            measured = np.asarray(meas["path_gain_db"], np.float64)[rows, 0]
        _refuse_large(model, len(rx) * len(txs_map), cfg)
        # receivers at (or next to) a transmitter: no far-field path gain there; left out of that map
        min_m = float(cfg["min_tx_distance_m"])
        near = np.stack([_near_tx(rx, t, min_m) for t in txs_map])            # [T, N]
        for i in np.flatnonzero(near.any(1)):
            which = f"transmitter {i + 1}" if several else "the transmitter"
            warnings.append(f"{int(near[i].sum())} receiver point(s) closer than {min_m:g} m to {which} at "
                            f"({', '.join(f'{x:.2f}' for x in txs_map[i])}) left out of its map (NaN; "
                            "predict.rssi.min_tx_distance_m)")
        if near.all():
            raise StageError(f"every receiver is closer than {min_m:g} m to the transmitter: nothing to predict")
        keep = ~near
        t_idx, r_idx = np.nonzero(keep)                                       # links: transmitter-major
        txs, rx_links = txs_map[t_idx], rx[r_idx]
        warnings += check_points(model.geometry, txs_map, "transmitter", bounds, provider=model.provider)
    else:
        txs, rx_links = np.asarray(meas["tx_pos"], np.float64), np.asarray(meas["rx_pos"], np.float64)
        measured = np.asarray(meas["path_gain_db"], np.float64)[:, 0]
        rx = rx_links
        _refuse_large(model, len(rx), cfg)
        warnings += check_points(model.geometry, np.unique(txs, axis=0), "transmitter", bounds, provider=model.provider)
    warnings += check_points(model.geometry, rx, "receiver", bounds, provider=model.provider)   # the CLI prints them
    axes, axes_note = link_axes_for(model, meas if txs_map is None else None, measurements_path)
    warnings += axes_note

    t0 = time.time()
    with progress.task("predict rssi", total=len(rx_links)) as bar:
        pg_all = _path_gain_blocks(model, txs, rx_links, freqs, int(cfg["chunk_links"]), bar, axes)
    pg = pg_all[:, 0]
    predict_s = time.time() - t0

    metrics, test = {}, None
    maps = None
    if txs_map is None:
        test, train, protocol = model.held_out_rows(meas)
        split = np.zeros(len(rx), np.int64)
        split[test] = 1
        metrics = {"split": protocol, "num_test": int(test.size), "num_train": int(train.size),
                   "mae_db": float(np.mean(np.abs(pg[test] - measured[test]))),
                   "mae_train_db": float(np.mean(np.abs(pg[train] - measured[train])))}
        labels = rf.get("gaussians/labels")
        metrics.update(_baselines(pg, rf, labels, model.provider, txs, rx, measured, train, test))
        warnings += baselines_beating_model(metrics)   # printed and in the results JSON
        warnings += baselines_beating_model({"mae_db": metrics["mae_train_db"], **{
            k.replace("_mae_train_db", "_mae_db"): v for k, v in metrics.items() if k.endswith("_mae_train_db")}},
            rows="training")
    else:
        maps = np.full(keep.shape, np.nan)                                    # [T, N] path gain dB, NaN: left out
        maps[t_idx, r_idx] = pg
        if measured is not None:
            measured = measured[keep[0]]
            metrics = {"mae_db_this_tx": float(np.mean(np.abs(pg - measured))), "num_points": int(len(pg))}
        if tx_power_dbm is not None:
            maps = maps + float(tx_power_dbm)
        best_idx, best = rssi_maps.best_server(maps)
        if several:
            metrics["best_tx_points"] = [int(np.count_nonzero(best_idx == i)) for i in range(len(txs_map))]
        if threshold_dbm is not None:
            share, covered, n = rssi_maps.coverage_share(best, threshold_dbm)
            metrics.update(coverage_share=share, coverage_points=covered, coverage_of_points=n,
                           threshold_dbm=float(threshold_dbm))
        if tx_power_dbm is not None:
            metrics["tx_power_dbm"] = float(tx_power_dbm)

    data = {"tx_pos": txs, "rx_pos": rx_links, "freq_hz": np.asarray(freqs, np.float64), "path_gain_db": pg_all}
    if measured is not None and len(freqs) == 1:   # one frequency measured: a column of several would repeat it
        data["measured_db"] = measured[:, None]
    if split is not None:
        data["split"] = split
    prov = Provenance(stage="predict.rssi", config_toml=config_toml)
    prov.add_input(rf_path)
    if measurements_path is not None:
        prov.add_input(measurements_path)
    if rx_file is not None:
        prov.add_input(rx_file)
    prov.wall_time_s = time.time() - t_start
    prov.extra = {"predict_time_s": predict_s, "seed": seed, "warnings": "; ".join(warnings)}
    flat = {k: v for k, v in metrics.items() if isinstance(v, (int, float, str))}
    attrs = {"task": "rssi", "quantity": "path_gain_db"}
    if tx_power_dbm is not None:
        attrs["tx_power_dbm"] = float(tx_power_dbm)   # the map files and plots are in dBm; path_gain_db stays dB
    write_artifact(out_path, "predictions", data, attrs=attrs, provenance=prov,
                   free={"metrics": {"@attrs": flat}} if flat else None)
    result = RssiPredictResult(out_path, len(rx_links), freq_hz, time.time() - t_start, predict_s, metrics,
                               warnings, freqs_hz=[float(f) for f in freqs], freq_assumed=freqs_hz is None)
    if maps is not None:
        result.num_tx, result.unit = len(txs_map), "dBm" if tx_power_dbm is not None else "dB"
        result.tx_m, result.map_points = txs_map, len(rx)
        result.map_stats = [_stats(m) for m in maps]
        quantity = "received power" if tx_power_dbm is not None else "path gain"
        result.map_files = rssi_maps.write_maps(rssi_maps.map_paths(out_path, formats, len(txs_map)), rx, maps,
                                                txs_map, result.unit, quantity, grid_info)
    if plots_dir is not None:
        if maps is not None:
            result.plots = _map_plots(Path(plots_dir), model, rf, txs_map, rx, maps, measured, keep[0], tx_power_dbm,
                                      threshold_dbm)
        else:
            result.plots = _plots(Path(plots_dir), model, rf, meas, txs, rx, pg, measured, test)
    if results_path is not None and metrics:
        result.results_json = _results(Path(results_path), name or out_path.stem, rf, rf_path, measurements_path,
                                       result, seed)
    return result


def _stats(values: np.ndarray) -> dict:
    """Median, minimum and maximum of a map's values (NaN left out) and how many are NaN."""
    v = np.asarray(values, np.float64)
    have = v[np.isfinite(v)]
    if not have.size:
        return {"median": np.nan, "min": np.nan, "max": np.nan, "left_out": int(v.size)}
    return {"median": float(np.median(have)), "min": float(have.min()), "max": float(have.max()),
            "left_out": int(v.size - have.size)}


def _floor_xy(model: RadioModel) -> np.ndarray:
    means = model.geometry.means.numpy()
    z_lo, z_hi = means[:, 2].min(), means[:, 2].max()
    return means[(means[:, 2] > z_lo + 0.05) & (means[:, 2] < z_hi - 0.05), :2]   # walls and objects


def _map_plots(folder: Path, model: RadioModel, rf, txs_map, rx, maps, measured, kept, tx_power_dbm,
               threshold_dbm) -> list:
    """Heatmaps of a map request (points left out of a map blank): each transmitter's map (rssi_predicted.png
    for one, rssi_predicted_txI.png for several), measured and error for one measured transmitter, the best
    server (several), the coverage (with a threshold) and the FoV attribute renders from the first transmitter.
    Colour bars say the unit: received power [dBm] with tx_power_dbm, else path gain [dB]."""
    floor = _floor_xy(model)
    dbm = tx_power_dbm is not None
    label = "received power [dBm]" if dbm else "path gain [dB]"
    what = f"predicted received power (P_T = {tx_power_dbm:g} dBm)" if dbm else "predicted path gain"
    ghz = f"{model.default_freqs()[0] / 1e9:g} GHz"
    at = lambda t: f"({', '.join(f'{x:.2f}' for x in t)}) m"   # noqa: E731
    import matplotlib

    several = len(txs_map) > 1
    paths = []
    for i, (t, m) in enumerate(zip(txs_map, maps)):
        shown = np.isfinite(m)
        vals = m[shown] if measured is None else np.concatenate([m[shown], measured + (tx_power_dbm or 0.0)])
        lo, hi = (float(vals.min()), float(vals.max())) if vals.size else (None, None)
        name = f"rssi_predicted_tx{i + 1}.png" if several else "rssi_predicted.png"
        paths.append(radio_map(folder / name, rx, m, t, floor, f"{what}, Tx {at(t)}, {ghz}", label,
                               vmin=lo, vmax=hi))
        if measured is not None and not several:
            meas = measured + (tx_power_dbm or 0.0)
            err = m[kept] - meas
            paths.append(radio_map(folder / "rssi_measured.png", rx[kept], meas, t, floor,
                                   f"measured {'received power' if dbm else 'path gain'}, Tx {at(t)}, {ghz}", label,
                                   vmin=lo, vmax=hi))
            e_lo, e_hi = error_limits(err)
            paths.append(radio_map(folder / "rssi_error.png", rx[kept], err, t, floor,
                                   f"error (predicted - measured), Tx {at(t)}, {ghz}; MAE {np.mean(np.abs(err)):.2f} dB",
                                   "error [dB]", cmap="RdBu_r", vmin=e_lo, vmax=e_hi))
    best_idx, best = rssi_maps.best_server(maps)
    have = best_idx >= 0
    if several:
        paths.append(radio_map(folder / "best_tx.png", rx, np.where(have, best_idx + 1.0, np.nan), txs_map[0], floor,
                               f"best server (strongest of {len(txs_map)} transmitters; star: Tx 1), {ghz}",
                               "transmitter", cmap=matplotlib.colormaps["tab10"].resampled(len(txs_map)), vmin=0.5,
                               vmax=len(txs_map) + 0.5))
    if threshold_dbm is not None:
        share, _, _ = rssi_maps.coverage_share(best, threshold_dbm)
        paths.append(radio_map(folder / "coverage.png", rx, np.where(have, best >= threshold_dbm, np.nan),
                               txs_map[0], floor, f"coverage: {100 * share:.1f} % of the points at or above "
                               f"{threshold_dbm:g} dBm, {ghz}", "covered (1) or not (0)", cmap="RdYlGn",
                               vmin=0.0, vmax=1.0))
    paths.append(fov_maps(folder / "fov_attributes.png", model.geometry, rf, txs_map[0]))
    return paths


def _plots(folder: Path, model: RadioModel, rf, meas, txs, rx, pg, measured, test) -> list:
    means = model.geometry.means.numpy()
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
    where = f"Tx ({', '.join(f'{x:.2f}' for x in tx)}) m, {model.default_freqs()[0] / 1e9:g} GHz"
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
    paths.append(fov_maps(folder / "fov_attributes.png", model.geometry, rf, tx))
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
