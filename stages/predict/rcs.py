"""`rfir predict rcs`: monostatic RCS from an `rf` artifact, beside measurements when given.

Links come from the measurement file (every row, its split kept) or from --aspects x --ranges in
simulate's turntable convention. The physical model and antenna are the ones recorded by rf-fit
(rfir_stages.model.artifact; group model/). Outputs: a `predictions` artifact (path_gain_db,
rcs_dbsm, measured_db = measured RCS), optional PNG plots (polar and linear RCS versus aspect per
range and frequency; the fitted materials' |Gamma| at normal incidence and S seen from the first
aspect) and a results JSON (default: the output with .json) with the MAE on the test split beside the nearest-aspect and
linear-interpolation baselines, and the flashes among the test rows (flashes.py) for each of them.
"""
from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rfir_core.artifacts import check_output, read_artifact, write_artifact
from rfir_core.errors import ConfigError, StageError
from rfir_core.physics.closed_forms import rcs_from_path_gain
from rfir_core.progress import NullProgress
from rfir_core.provenance import Provenance
from rfir_stages.importers.select import select_rows
from rfir_stages.diagnose.apply import apply_recorded_effects
from rfir_stages.model.antenna_patterns import antenna_from_attrs
from rfir_stages.model.artifact import has_residual
from rfir_stages.model.links import check_overlap, check_positions, radar_links, scene_centre
from rfir_stages.model.radio_model import load_model
from rfir_stages.model.split_protocols import describe as describe_split

from .attribute_maps import plot_attribute_maps, render_attribute_maps
from .baselines import aspect_baselines, baselines_beating_model, range_baselines
from .flashes import flash_defaults, score_flashes
from .plots import attribute_views, rcs_vs_aspect
from .wideband import is_band_fit, spectrum_plots


@dataclass
class PredictResult:
    """Summary of one prediction run. metrics: name -> value (MAE in dB on the test split)."""

    path: Path
    num_links: int
    freqs_hz: list
    wall_time_s: float
    render_time_s: float
    metrics: dict = field(default_factory=dict)
    plots: list = field(default_factory=list)
    results_json: Path | None = None
    flashes: dict | None = None   # flashes on the test rows (flashes.score_flashes), with measurements


def predict_path_gain_db(rf, tx, rx, freqs, task: str = "rcs", *, occlusion: str = "auto", chunk_links: int = 64,
                         progress=None) -> np.ndarray:
    """Path gain [L, K] dB predicted by the RCS model of an `rf` artifact (any frequency; docs/physics.md
    section 8) for links tx/rx [L, 3] m at freqs [K] Hz, without the effects diagnose recorded. One call: a
    caller that predicts more than once keeps the model of rfir_stages.model.radio_model.load_model."""
    model = load_model(rf, quantity="rcs", occlusion=occlusion)
    return model.predict(tx, rx, freqs, progress=progress, chunk_links=chunk_links)


def _assert_not_input(out: Path, inputs: list[Path]) -> None:
    for p in inputs:
        if p is not None and out.resolve() == Path(p).resolve():
            raise ConfigError(f"-o {out} would overwrite the input {p}; predicting never overwrites its inputs")


def run_rcs(rf_path, out_path, config: dict, *, measurements_path=None, aspects_deg=None, ranges_m=None,
            freqs_hz=None, plots_dir=None, results_path=None, name: str | None = None, seed: int = 0,
            config_toml: str = "", progress=None, select=None) -> PredictResult:
    """Predict monostatic RCS; see the module docstring. config: the [predict] table. select: a
    rfir_stages.importers.select.RowSelection of measured rows (ranges, aspect intervals)."""
    progress = progress or NullProgress()
    t_start = time.time()
    rf_path, out_path = Path(rf_path), Path(out_path)
    _assert_not_input(out_path, [rf_path, measurements_path])
    if results_path is not None:
        _assert_not_input(Path(results_path), [rf_path, measurements_path])
    check_output(out_path, "predictions", [p for p in (rf_path, measurements_path) if p is not None])
    rf = read_artifact(rf_path, "rf")
    model = load_model(rf, quantity="rcs", occlusion=str(config.get("occlusion", "auto")))
    geom = model.geometry
    centre = scene_centre(geom).numpy()
    meas = None
    if measurements_path is not None:
        meas = read_artifact(measurements_path, "measurements")
        check_overlap(geom, meas, str(measurements_path))
        if meas.get("aspect_rad") is None or meas.get("range_m") is None or meas.get("rcs_dbsm") is None:
            raise StageError("measurements for `predict rcs` need aspect_rad, range_m and rcs_dbsm",
                             path=measurements_path)
        tx, rx = np.asarray(meas["tx_pos"]), np.asarray(meas["rx_pos"])
        asp, rng = np.asarray(meas["aspect_rad"]), np.asarray(meas["range_m"])
        f_all = np.asarray(meas["freq_hz"], np.float64)
        # any measured frequency that is asked for (default: the fitted ones, or a band fit's band)
        want = model.default_freqs(f_all) if freqs_hz is None else np.asarray(freqs_hz, np.float64)
        cols = np.flatnonzero([np.any(np.abs(want - f) <= 1e-6 * f) for f in f_all])
        if cols.size == 0:
            raise StageError("none of the measured frequencies was fitted "
                             f"(measured {', '.join(f'{x / 1e9:g}' for x in f_all[:8])} GHz)", path=measurements_path)
        freqs = f_all[cols]
        meas_rcs = np.asarray(meas["rcs_dbsm"], np.float64)[:, cols]
        split = model.training_split(meas)   # 0 train, 1 test, -1 unused, as the fit split the rows
        rows = np.arange(len(tx))
        if aspects_deg is not None:  # a subset of the measured rows
            keep = np.any(np.abs(np.mod(asp[:, None] - np.radians(aspects_deg)[None] + math.pi, 2 * math.pi)
                                 - math.pi) < 1e-6, axis=1)
            rows = rows[keep]
        if ranges_m is not None:
            rows = rows[np.any(np.abs(rng[rows, None] - np.asarray(ranges_m)[None]) < 1e-6, axis=1)]
        if select:
            rows, _ = select_rows(meas, select, str(measurements_path), rows)
        if rows.size == 0:
            raise StageError("no measured row matches --aspects / --ranges", path=measurements_path)
        tx, rx, asp, rng, meas_rcs, split = tx[rows], rx[rows], asp[rows], rng[rows], meas_rcs[rows], split[rows]
    else:
        aspects = np.radians(np.arange(0.0, 360.0, 1.0) if aspects_deg is None else np.asarray(aspects_deg, float))
        ranges = np.asarray([3.0] if ranges_m is None else ranges_m, float)
        freqs = model.default_freqs() if freqs_hz is None else np.asarray(freqs_hz, np.float64)
        tx, rx, asp, rng = radar_links(aspects, ranges, centre, float(config.get("separation_m", 0.002)))
        meas_rcs, split = None, None
    check_positions(geom, np.concatenate([tx, rx]), "links", float(config.get("min_clearance_m", 0.02)))
    ant = antenna_from_attrs(rf.free.get("model@attrs", {}))

    t0 = time.time()
    # a model with a residual: the physics alone is scored beside it
    pg_db, physics_db = model.predict_with_physics_only(tx, rx, freqs, progress=progress,
                                                        chunk_links=int(config.get("chunk_links", 64)),
                                                        physics_only=has_residual(rf))
    render_s = time.time() - t0
    pg_db = apply_recorded_effects(rf, pg_db, tx, rx, freqs, aspect_rad=asp, range_m=rng)   # named by `rfir diagnose`
    g0 = ant.boresight_gain
    rcs = 10 * np.log10(rcs_from_path_gain(10 ** (pg_db / 10), rng[:, None], freqs[None], g0, g0))

    base = _test_baselines(meas_rcs, split, asp, rng) if meas_rcs is not None else {}
    metrics = _metrics(rcs, meas_rcs, split, base) if meas_rcs is not None else {}
    rcs_phys = None
    if physics_db is not None and metrics.get("num_test"):
        physics_db = apply_recorded_effects(rf, physics_db, tx, rx, freqs, aspect_rad=asp, range_m=rng)
        rcs_phys = 10 * np.log10(rcs_from_path_gain(10 ** (physics_db / 10), rng[:, None], freqs[None], g0, g0))
        test = split == 1
        metrics["mae_db_physics_only"] = float(np.mean(np.abs(rcs_phys[test] - meas_rcs[test])))
    flashes = (_flashes(config, rcs, rcs_phys, meas_rcs, split, asp, rng, freqs, base)
               if metrics.get("num_test") else None)
    data = {"tx_pos": tx, "rx_pos": rx, "freq_hz": freqs, "path_gain_db": pg_db, "rcs_dbsm": rcs,
            "aspect_rad": asp, "range_m": rng}
    if meas_rcs is not None:
        data.update(measured_db=meas_rcs, split=split.astype(np.int64))
    prov = Provenance(stage="predict.rcs", config_toml=config_toml)
    prov.add_input(rf_path)
    if measurements_path is not None:
        prov.add_input(measurements_path)
    prov.wall_time_s = time.time() - t_start
    prov.extra = {"render_time_s": render_s, "seed": seed}
    free = {"metrics": {"@attrs": {k: v for k, v in _flat(metrics).items()}}} if metrics else None
    write_artifact(out_path, "predictions", data, attrs={"task": "rcs", "quantity": "rcs_dbsm"},
                   provenance=prov, free=free)

    result = PredictResult(out_path, len(tx), freqs.tolist(), time.time() - t_start, render_s, metrics,
                           flashes=flashes)
    if plots_dir is not None:
        result.plots = _plots(Path(plots_dir), rf, asp, rng, freqs, rcs, meas_rcs, split)
        if is_band_fit(rf):
            result.plots += spectrum_plots(Path(plots_dir), asp, rng, freqs, rcs, meas_rcs, split)
    if results_path is not None:
        result.results_json = _results(Path(results_path), name or out_path.stem, rf, rf_path, measurements_path,
                                       result, seed, split)
    return result


def _test_baselines(meas_rcs, split, asp, rng) -> dict:
    """The simple baselines' predictions of the test rows, name -> [T, F] dBsm, for those that predict
    any (aspect baselines need training rows at the test range, range ones at the aspect); {} without
    training or test rows. Scored by _metrics and _flashes."""
    test, train = np.flatnonzero(split == 1), np.flatnonzero(split == 0)
    if not (test.size and train.size):
        return {}
    base = aspect_baselines(asp, rng, meas_rcs, train, test)
    base.update(range_baselines(asp, rng, meas_rcs, train, test))
    return {k: v for k, v in base.items() if np.isfinite(v).any()}


def _metrics(rcs, meas_rcs, split, base: dict) -> dict:
    """MAE of rfir and of each baseline of _test_baselines (base) on the test rows."""
    test, train = np.flatnonzero(split == 1), np.flatnonzero(split == 0)
    out = {"num_test": int(test.size), "num_train": int(train.size)}
    if test.size == 0:
        return out
    out["mae_db"] = float(np.mean(np.abs(rcs[test] - meas_rcs[test])))
    out["mae_db_per_freq"] = np.mean(np.abs(rcs[test] - meas_rcs[test]), axis=0).tolist()
    if train.size:
        out["mae_train_db"] = float(np.mean(np.abs(rcs[train] - meas_rcs[train])))
        for k, v in base.items():
            out[f"baseline_{k}_mae_db"] = float(np.nanmean(np.abs(v - meas_rcs[test])))
        beaten = baselines_beating_model(out)
        if beaten:   # said in the closing lines (predict rcs) and the results JSON
            out["warning_baselines"] = "; ".join(beaten)
    return out


def _flashes(config: dict, rcs, rcs_phys, meas_rcs, split, asp, rng, freqs, base: dict | None = None) -> dict:
    """Flashes among the test rows (flashes.py) scored for rfir, the physics alone when a residual is
    applied, and each baseline that predicts the test rows (base: _test_baselines, computed when not
    given). rcs, rcs_phys, meas_rcs [L, F] dBsm."""
    test = np.flatnonzero(split == 1)
    predictions = {"rfir": rcs} if rcs_phys is None else {"rfir": rcs, "physics_only": rcs_phys}
    for k, v in (_test_baselines(meas_rcs, split, asp, rng) if base is None else base).items():
        full = np.full(meas_rcs.shape, np.nan)
        full[test] = v
        predictions[k] = full
    cfg = flash_defaults() | dict(config.get("flashes", {}))
    return score_flashes(asp, rng, freqs, meas_rcs, split == 1, predictions,
                         min_prominence_db=float(cfg["min_prominence_db"]), window_deg=float(cfg["window_deg"]),
                         tolerance_db=float(cfg["tolerance_db"]))


def _flat(metrics: dict) -> dict:
    return {k: (np.asarray(v, float) if isinstance(v, list) else v) for k, v in metrics.items()}


def _plots(folder: Path, rf, asp, rng, freqs, rcs, meas_rcs, split) -> list:
    paths = []
    for r in np.unique(np.round(rng, 6))[:4]:
        sel = np.abs(rng - r) < 1e-6
        for k, f in enumerate(freqs[:4]):
            stem = f"rcs_{f / 1e9:g}GHz_{r:g}m"
            title = f"RCS at {f / 1e9:g} GHz, range {r:g} m"
            m = None if meas_rcs is None else meas_rcs[sel, k]
            s = None if split is None else split[sel]
            for polar in (True, False):
                paths.append(rcs_vs_aspect(folder / f"{stem}_{'polar' if polar else 'linear'}.png", asp[sel],
                                           rcs[sel, k], m, s, title, polar))
    a0 = float(asp[0])
    view = -np.array([math.cos(-a0), math.sin(-a0), 0.0])
    index = np.asarray(rf["material/index"])   # the fitted materials: |Gamma| at normal incidence, S, which material
    attributes = {"|Gamma| at normal incidence": np.asarray(rf["rf/gamma_abs"]),
                  "scattering S": np.asarray(rf["material/scattering"])[index],
                  "material": index.astype(np.float64), "RF opacity a": np.asarray(rf["rf/opacity"])}
    paths.append(attribute_views(folder / "attributes.png", np.asarray(rf["gaussians/means"]), attributes, view))
    # the paper's attribute maps: rendered through the tracer from the radar at the first aspect
    means = np.asarray(rf["gaussians/means"])
    centre = 0.5 * (means.min(0) + means.max(0))
    eye = centre - view * float(rng[0])
    maps = render_attribute_maps(means, rf["gaussians/log_scales"], rf["gaussians/rotations"], rf["rf/opacity"],
                                 {k: v for k, v in attributes.items() if k != "RF opacity a"}, eye, centre)
    paths.append(plot_attribute_maps(folder / "attribute_maps.png", maps,
                                     f"RF attributes seen from the radar at aspect {math.degrees(a0):.0f} deg, "
                                     f"{float(rng[0]):g} m"))
    return paths


def _results(path: Path, name, rf, rf_path, measurements_path, result: PredictResult, seed, split) -> Path:
    training = rf.free.get("training@attrs", {})
    doc = {
        "name": name, "task": "rcs", "scene": str(rf.attrs.get("scene", "")),
        "freqs_hz": result.freqs_hz, "rf": str(rf_path), "measurements": str(measurements_path),
        "split": describe_split(str(training.get("split", "data"))),
        "split_protocol": str(training.get("split", "data")),
        "num_test": result.metrics.get("num_test"), "num_train": result.metrics.get("num_train"),
        "num_gaussians": int(len(rf["rf/opacity"])), "seed": seed,
        "metrics": result.metrics,
        **({"flashes_test": result.flashes} if result.flashes is not None else {}),
        "fit": {k: (v.item() if hasattr(v, "item") else v) for k, v in training.items()},
        "predict_wall_time_s": result.wall_time_s, "predict_render_time_s": result.render_time_s,
        "num_links": result.num_links,
        "antenna": {k: str(v) for k, v in rf.free.get("model@attrs", {}).items()
                    if k in ("antenna_kind", "antenna_hpbw_deg", "antenna_source")},
        "model_terms": {k: bool(rf.free.get("model@attrs", {}).get(f"pairs.{k}", True))
                        for k in ("visibility", "second_order")},
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(json.dumps(doc, indent=2, default=str) + "\n")
    tmp.replace(path)
    return path
