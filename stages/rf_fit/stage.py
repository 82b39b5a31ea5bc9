"""`rfir rf-fit`: the physical radio model (rfir_stages.model) fitted to the training split of a measurement file.

run(scene.h5, measurements.h5, rf.h5, config) reads a `scene` (or `rf`) artifact and a
`measurements` artifact, traces the geometry of every (training link, lit surfel) pair once, fits
the materials (eps_r, sigma, thickness, S; docs/physics.md) of each material sharing candidate
chosen by validation, refits the best on every training link, fits the residual on top and writes
the `rf` artifact of rfir_stages.model.artifact: the scene's Gaussians, material/*, rf/* (the
attribute-map values), residual/*; group model/ (the model's settings as attributes) and group
training/ (loss curve, training rows, MAEs, model selection). RSSI measurements go to the room
model (rssi_fit.py); wideband ones are a band of the same physical model (wideband_stage.py).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from pathlib import Path

import numpy as np
import torch

from rfir_core.artifacts import check_output, read_artifact, write_artifact
from rfir_core.errors import ConfigError, InputFileError
from rfir_core.progress import NullProgress
from rfir_core.provenance import Provenance
from rfir_core.text import plural
from rfir_stages.importers.select import select_rows
from rfir_stages.model.band import aggregate_chunk
from rfir_stages.model.fit_physical import material_index, reflection_ranges
from rfir_stages.model.sampling import cell_size_m, coarse_surfels_warning

from rfir_stages.model.antenna_patterns import antenna_choice
from rfir_stages.model.links import check_overlap, check_positions, geometry_from_artifact, make_links, pick_freqs, scene_centre
from rfir_stages.model.occlusion import make_provider
from .physical_stage import (PhysicalSetup, attach_ranges, bound_warnings, mae_db, material_table,
                             physical_artifact_fields, physical_config, range_words, residual_training_attrs,
                             edge_waves_mode, selection_rule, sharing_candidates, split_candidate)
from rfir_stages.model.link_set import RenderSettings
from rfir_stages.model.split_protocols import describe as describe_split
from rfir_stages.model.split_protocols import protocol_masks, split_rows
from rfir_stages.model.validation_folds import MIN_VALIDATION_LINKS, validation_folds
from .result import RfFitResult
from .rssi_fit import run_rssi
from .wideband_stage import band_config, is_wideband_request


def sharing_words(sharing: str) -> str:
    """'materials per label', 'materials per object class', 'materials per segment' or 'one material for
    the scene'."""
    base, edges = split_candidate(sharing)
    if edges:
        return f"{sharing_words(base)} with edge waves"
    if sharing == "global":
        return "one material for the scene"
    return "materials per object class" if sharing == "class" else f"materials per {sharing}"


def render_settings(cfg: dict) -> RenderSettings:
    """The tracing settings of the [rf_fit] table (unknown keys were refused upstream)."""
    kw = {k: cfg[k] for k in ("visibility", "alpha_min", "t_stop", "colocated_tol_m") if k in cfg}
    if "opacity" in cfg:
        kw["visibility_opacity"] = float(cfg["opacity"])
    return RenderSettings(**kw)


def _key(*parts) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def run(scene_path, measurements_path, out_path, config: dict, *, seed: int = 0, config_toml: str = "",
        progress=None, checkpoint: Path | None = None, resume: bool = False, select=None,
        t_start: float | None = None, device: str = "cpu") -> RfFitResult:
    """Fit the physical model; see the module docstring. device: where the tracer runs the frozen
    visibility ("cpu" or "cuda"; the fit itself is small and stays on the CPU). config: the [rf_fit] table. select: a
    rfir_stages.importers.select.RowSelection of ranges / aspects narrowing the training rows.
    The material sharing chosen by validation is recorded in CHECKPOINT.selection (checkpoint default:
    OUT.ckpt.pt); resume: reuse that record when it was made for the same run, instead of selecting again."""
    progress = progress or NullProgress()
    t_start = time.time() if t_start is None else t_start   # when the command began: the wall time covers it all
    scene_path, measurements_path, out_path = Path(scene_path), Path(measurements_path), Path(out_path)
    if out_path.resolve() in (scene_path.resolve(), measurements_path.resolve()):
        raise ConfigError(f"-o {out_path} would overwrite an input")
    check_output(out_path, "rf", (scene_path, measurements_path))   # another kind of file: before the fit, not after
    torch.manual_seed(seed)
    render_cfg = render_settings(config)
    scene = read_artifact(scene_path, ("scene", "rf"))
    meas = read_artifact(measurements_path, "measurements")
    task = str(meas.attrs.get("task", ""))
    if task != "rssi":   # the room model takes each end's antenna itself (rssi_fit: antenna_patterns.room_antennas)
        ant = antenna_choice(config, meas, task, str(measurements_path))
        progress.log(f"rf-fit: {ant.note()}")
    if "polarisation" in meas.attrs:   # the physical model uses what the measurements state
        phys = dict(config.get("physical") or {})
        if str(phys.get("polarisation", "V")).upper() != meas.attrs["polarisation"]:
            progress.log(f"rf-fit: polarisation {meas.attrs['polarisation']} (stated by the measurements; "
                         f"rf_fit.physical.polarisation {phys.get('polarisation', 'V')} not used)")
        config = dict(config, physical=dict(phys, polarisation=str(meas.attrs["polarisation"])))
    fit_cfg, pair_settings, phys_table = physical_config(config, render_cfg)   # refused here when wrong
    if task == "rssi":  # the room model (docs/physics.md section 8.10): stages/rf_fit/rssi_fit.py
        if resume:
            raise ConfigError("--resume: RSSI fits write no checkpoints yet")
        if select:
            raise ConfigError("--range / --aspects select rows of rcs or wideband measurements, not of rssi ones")
        return run_rssi(scene, meas, scene_path, measurements_path, out_path, config, render_cfg, fit_cfg, seed=seed,
                        config_toml=config_toml, progress=progress)
    geom = geometry_from_artifact(scene)
    check_overlap(geom, meas, str(measurements_path))
    protocol = str(config.get("split", "data"))
    rows, test_rows = split_rows(meas, protocol, str(measurements_path))
    if select:
        rows, _ = select_rows(meas, select, str(measurements_path), rows)
        progress.log(f"rf-fit: {select.describe()} keeps {len(rows)} training rows")
    band_attrs = {}
    if is_wideband_request(task, config):  # the physical model on the band (docs/physics.md section 7)
        config, band_attrs = band_config(config, meas, str(measurements_path), progress)
        fit_cfg, pair_settings, phys_table = physical_config(config, render_cfg)
    cols = pick_freqs(meas["freq_hz"], config.get("freqs_hz"), str(measurements_path))
    tx, rx = meas["tx_pos"][rows], meas["rx_pos"][rows]
    check_positions(geom, np.concatenate([tx, rx]), str(measurements_path), float(config.get("min_clearance_m", 0.02)))
    target = np.asarray(meas["path_gain_db"], dtype=np.float64)[np.ix_(rows, cols)]
    if not np.isfinite(target).all():
        raise InputFileError("path_gain_db has non-finite training values", path=measurements_path)
    max_links = int(config.get("max_links", 0))
    if max_links and len(rows) > max_links:  # evenly thinned (quick runs)
        keep = np.linspace(0, len(rows) - 1, max_links).round().astype(int)
        rows, tx, rx, target = rows[keep], tx[keep], rx[keep], target[keep]
    freqs = np.asarray(meas["freq_hz"], dtype=np.float64)[cols]
    centre = scene_centre(geom)
    links = make_links(tx, rx, freqs, centre, task)
    rng = meas.get("range_m")
    progress.log(f"rf-fit: rows used: {len(rows)} train, {len(test_rows)} test (split {protocol}); frequencies "
                 + (f"{', '.join(f'{f / 1e9:g}' for f in freqs)} GHz" if len(freqs) <= 8 else
                    f"{len(freqs)} from {freqs.min() / 1e9:g} to {freqs.max() / 1e9:g} GHz")
                 + ("" if rng is None else f"; ranges {', '.join(f'{r:g}' for r in np.unique(np.round(rng[rows], 6)))} m"))

    labels = scene.get("gaussians/labels")
    labels = None if labels is None else torch.as_tensor(np.asarray(labels))
    label_names = [str(n) for n in scene.attrs["label_names"]] if "label_names" in scene.attrs else None
    num_labels = num_classes = 0
    if labels is not None:
        num_labels = int(torch.unique(labels).numel())
        num_classes = len(material_index("class", geom.num, labels, label_names=label_names)[1])
    sharings = sharing_candidates(phys_table, num_labels, num_classes)
    if {split_candidate(s)[0] for s in sharings} == {"global"} and str(phys_table.get("sharing", "auto")) == "auto":
        progress.log("rf-fit: one object class among the labels: its material is the scene's "
                     "(rf_fit.physical.sharing = auto -> global)")
    t0 = time.time()
    provider = make_provider(str(config.get("occlusion", "auto")), geom, render_cfg.alpha_min, device) \
        if render_cfg.visibility else None
    progress.log(f"rf-fit: {geom.num} Gaussians, {plural(links.num, 'training link')} x {plural(len(freqs), 'frequency')}, "
                 f"occlusion {getattr(provider, 'name', 'off')}, antenna {ant.kind}, physical model: polarisation "
                 f"{pair_settings.polarisation}, sigma ~ f^{fit_cfg.sigma_exponent:g}, double bounces "
                 f"{'on' if pair_settings.second_order else 'off'}, triple bounces "
                 f"{'on' if pair_settings.second_order and pair_settings.third_order else 'off'}, edge waves "
                 f"{ {'auto': 'chosen by validation', True: 'on', False: 'off'}[edge_waves_mode(phys_table)]}, shadows "
                 + (f"lit/shadowed at transmittance {pair_settings.lit_threshold:g}" if pair_settings.lit_threshold > 0
                    else "soft (transmittance)")
                 + f", system gain {'fitted' if fit_cfg.fit_gain else '0 dB'}")
    with progress.task("trace (physical pairs)", total=1) as bar:
        physical = PhysicalSetup.trace(geom, links, ant, provider, pair_settings, labels, phys_table, seed,
                                       label_names)
        if band_attrs:   # many frequencies: aggregate in smaller pair chunks; the band goes into the artifact
            physical.agg_chunk, physical.extra_attrs = aggregate_chunk(len(freqs)), band_attrs
        bar.advance(1)
    trace_s = time.time() - t0

    selection = {"sharing_requested": str(phys_table.get("sharing", "auto")), "sharing_selected": sharings[0]}
    # A recorded selection fits any run with the same inputs, rows and settings (the refit's step count aside).
    settings = dict(config, physical={k: v for k, v in phys_table.items() if k != "iterations"})
    key = _key(str(scene_path.resolve()), str(measurements_path.resolve()), settings, seed, np.asarray(rows).tolist())
    ckpt = Path(checkpoint) if checkpoint is not None else out_path.with_name(out_path.name + ".ckpt.pt")
    chosen = ckpt.with_name(ckpt.name + ".selection")   # the model selection of this run, for --resume
    t_sel = time.time()
    reused = _load_selection(chosen, key) if resume and len(sharings) > 1 else None
    starts = []
    if reused is not None:
        selection = reused
        progress.log(f"rf-fit: model selection reused from {chosen}: {sharing_words(selection['sharing_selected'])}")
    elif len(sharings) > 1:
        asp, rng = meas.get("aspect_rad"), meas.get("range_m")
        folds, how = validation_folds(protocol, None if asp is None else np.degrees(np.asarray(asp)[rows]),
                                      None if rng is None else np.asarray(rng)[rows])
        selection.update(_select_sharing(physical, target, folds, how, sharings, fit_cfg, progress,
                                         selection_rule(phys_table)))
        starts = selection.pop("states", [])
        _save_selection(chosen, key, selection)
    select_s = time.time() - t_sel
    warnings = [selection.pop("warning")] if "warning" in selection else []
    coarse = coarse_surfels_warning(cell_size_m(geom.log_scales, geom.rotations, geom.normals, physical.areas_m2), freqs)
    if coarse:
        progress.log(f"warning: {coarse}")
        warnings.append(coarse)
    return _run_physical(physical, selection, target, fit_cfg, pair_settings, scene, meas, task, freqs, rows,
                         ant, protocol, scene_path, measurements_path, out_path, config_toml, seed, progress,
                         t_start, trace_s, select_s, geom.num, starts, warnings, device)


def _save_selection(path: Path, key: str, selection: dict) -> None:
    """The model selection's outcome beside the output, written to a temporary file and renamed, so
    that `--resume` after a kill does not select again."""
    tmp = path.with_name(path.name + ".partial")
    torch.save({"key": key, "selection": dict(selection)}, tmp)
    tmp.replace(path)


def _load_selection(path: Path, key: str) -> dict | None:
    """The saved selection when it was made for the same run, else None."""
    if not path.exists():
        return None
    try:
        record = torch.load(path, weights_only=True)
    except Exception as exc:  # noqa: BLE001 - a damaged record is a user-fixable input problem
        raise InputFileError(f"cannot read the saved model selection ({exc}); delete it", path=path) from None
    if not isinstance(record, dict) or record.get("key") != key or "selection" not in record:
        return None
    return dict(record["selection"])


def _select_sharing(physical: PhysicalSetup, target: np.ndarray, folds: list[np.ndarray], how: str,
                    sharings: list[str], fit_cfg, progress, rule: str = "one_se") -> dict:
    """The material sharing ("label" / "class" / "segment" / "global") that predicts held-out training rows best
    after the same fit on the rest. `folds`: lists of training rows held out in turn, shaped like the
    protocol's test by validation.validation_folds; the test split is never looked at. Fewer than 10
    training links: the first sharing. rule "one_se": the one-standard-error rule
    (one_standard_error_choice); "lowest": the lowest validation MAE. Returns {"sharing_selected",
    "validation_links", "validation", "val_mae_<sharing>_db", "fit_time_<sharing>_s", "validation_se_db",
    "states"} ("states": the selected sharing's fits per fold, PhysicalFitResult)."""
    m = len(target)
    val_all = np.concatenate(folds) if folds else np.zeros(0, np.int64)
    if m < 10 or len(val_all) == 0 or any(len(f) in (0, m) for f in folds):
        progress.log(f"rf-fit: choosing the material sharing by validation needs >= 10 training links and a "
                     f"validation set (got {m}); using {sharings[0]}")
        return {"why": "too few training links to validate"}
    out = {"validation_links": int(len(val_all)), "validation": how, "validation_folds": len(folds)}
    if len(val_all) < MIN_VALIDATION_LINKS:
        out["warning"] = (f"the material sharing was chosen on {len(val_all)} validation links (< "
                          f"{MIN_VALIDATION_LINKS}): the choice may be noise; more training rows make it firmer")
        progress.log(f"warning: {out['warning']}")
    scores, states, errors = {}, {}, {}
    for sharing in sharings:
        t0 = time.time()
        pred = np.zeros((len(val_all), target.shape[1]))
        states[sharing] = []
        at = 0
        for val in folds:
            fit_rows = np.setdiff1d(np.arange(m), val)
            res = physical.fit(sharing, fit_rows, target[fit_rows], fit_cfg, progress)
            pred[at:at + len(val)] = physical.predict_db(sharing, val, res.params)
            states[sharing].append(res)
            at += len(val)
        scores[sharing] = mae_db(pred, target[val_all])
        errors[sharing] = np.abs(pred - target[val_all])
        out[f"val_mae_{sharing}_db"] = scores[sharing]
        out[f"fit_time_{sharing}_s"] = time.time() - t0
    materials = {sharing: len(physical.for_sharing(sharing)[2]) for sharing in sharings}
    chosen, best, se = one_standard_error_choice(scores, errors, materials)
    if rule == "lowest":
        chosen = best
    out.update(sharing_selected=chosen, validation_se_db=se, states=states[chosen])
    why = "" if chosen == best else (f" (within one standard error, {se:.2f} dB, of {sharing_words(best)}: "
                                     f"{materials[chosen]} material{'s' * (materials[chosen] > 1)} "
                                     f"instead of {materials[best]})")
    progress.log(f"rf-fit: validation MAE on {len(val_all)} held-out training links ({how}): "
                 + ", ".join(f"{sharing_words(s)} {v:.2f} dB" for s, v in scores.items())
                 + f" -> {chosen}{why}")
    return out


def one_standard_error_choice(scores: dict, errors: dict, materials: dict) -> tuple[str, str, float]:
    """The candidate with the fewest materials whose validation MAE is within one standard error of the
    best's (the one-standard-error rule; ties in material count go to the lower score): the free
    parameters grow with the materials, and on a few held-out links a richer model's lower score is often
    noise. scores {candidate: MAE dB}; errors {candidate: |error| dB of
    each held-out entry}; materials {candidate: count}. Returns (chosen, best, standard error dB: of the
    best's mean absolute error over its held-out entries)."""
    best = min(scores, key=scores.get)
    err = np.asarray(errors[best], np.float64)
    err = err[np.isfinite(err)]
    se = float(np.std(err, ddof=1) / np.sqrt(err.size)) if err.size > 1 else 0.0
    within = [c for c in scores if scores[c] <= scores[best] + se]
    return min(within, key=lambda c: (materials[c], scores[c])), best, se


def _run_physical(physical: PhysicalSetup, selection: dict, target: np.ndarray, phys_cfg, pair_settings, scene, meas,
                  task: str, freqs: np.ndarray, rows: np.ndarray, ant, protocol: str, scene_path: Path,
                  measurements_path: Path, out_path: Path, config_toml: str, seed: int, progress, t_start: float,
                  trace_s: float, select_s: float, num_gaussians: int, starts: list | None = None,
                  warnings: list | None = None, device: str = "cpu") -> RfFitResult:
    """Refit the selected physical candidate on every training link and write the rf artifact.
    starts: the candidate's fits in model selection (PhysicalFitResult per fold); when one of them
    predicts every training link better than the refit, it is kept (a refit never ends worse)."""
    sharing = selection["sharing_selected"]
    t_fit = time.time()
    result = physical.fit(sharing, None, target, phys_cfg, progress)
    every = np.arange(len(target))
    for cand in starts or []:
        err = mae_db(physical.predict_db(sharing, every, cand.params), target)
        if err < result.train_mae_db:
            progress.log(f"rf-fit: the model-selection fit predicts the training links better ({err:.3f} dB) "
                         f"than the refit ({result.train_mae_db:.3f} dB): kept")
            result = dataclasses.replace(result, params=cand.params, train_mae_db=err)
    refit_s = time.time() - t_fit
    asp, rng = meas.get("aspect_rad"), meas.get("range_m")   # the residual on top (rfir_stages.model.residual)
    tx, rx = np.asarray(meas["tx_pos"])[rows], np.asarray(meas["rx_pos"])[rows]
    residual = physical.fit_residual(sharing, result, target, tx, rx, protocol,
                                     None if asp is None else np.degrees(np.asarray(asp)[rows]),
                                     None if rng is None else np.asarray(rng)[rows], progress)
    agg, _, names = physical.for_sharing(sharing)
    table = material_table(result, names, freqs)
    t_ranges = time.time()
    ranges = (reflection_ranges(agg, result.params, target, float(freqs[0]), progress=progress)
              if phys_cfg.reflection_ranges else None)
    attach_ranges(table, ranges)
    ranges_s = time.time() - t_ranges
    warnings = list(warnings or [])
    unseen = physical.unseen_materials(sharing)
    if unseen:
        warnings.append(f"no training link sees {', '.join(unseen)}: kept at the starting material "
                        f"({result.start}); predictions there are not fitted")
    warnings += bound_warnings(table)
    for w in warnings:
        progress.log(f"warning: {w}")
    data, model_attrs = physical_artifact_fields(physical, sharing, result, freqs, pair_settings, residual, tx, rx)
    data.update({k: v for k, v in scene.data.items() if k.startswith("gaussians/")})
    data["rf/freq_hz"] = np.asarray(freqs, dtype=np.float64)
    if ranges is not None:
        data["material/gamma_normal_range"] = np.asarray(ranges, dtype=np.float64)
    model_attrs.update(ant.describe())
    training_attrs = _training_attrs(meas, protocol, rows, selection, seed)
    training_attrs.update({"loss": phys_cfg.loss, "iterations": phys_cfg.iterations, "lr": phys_cfg.lr,
                           "sharing": sharing, "train_mae_db": result.train_mae_db,
                           "initial_mae_db": result.initial_mae_db, "start_material": result.start,
                           "warnings": "; ".join(warnings)})
    training_attrs.update(residual_training_attrs(residual))
    timings = {"trace": trace_s, "select": select_s, "fit": refit_s, "residual": residual.wall_time_s,
               "ranges": ranges_s, "total": time.time() - t_start}
    training_attrs.update(_timing_attrs(timings))
    prov = Provenance(stage="rf-fit", config_toml=config_toml, device=device)   # where the tracing ran
    prov.add_input(scene_path)
    prov.add_input(measurements_path)
    prov.wall_time_s = timings["total"]
    prov.extra = {"seed": seed, "train_rows": int(len(rows)), "trace_time_s": trace_s,
                  "fit_time_s": refit_s, "selection_time_s": select_s}
    free = {"model": {"@attrs": model_attrs},
            "training": {"loss_curve": result.loss_curve, "train_rows": np.asarray(rows, dtype=np.int64),
                         "@attrs": training_attrs}}
    root = dict(_root_attrs(scene, meas, task), edge_waves="on" if split_candidate(sharing)[1] else "off")
    write_artifact(out_path, "rf", data, attrs=root, provenance=prov, free=free)
    progress.log("rf-fit: materials " + "; ".join(
        f"{r['material']}: eps_r {r['eps_r']:.2f}, sigma {r['sigma_s_per_m']:.3g} S/m, S {r['scattering']:.2f}, "
        f"d {r['thickness_m'] * 1e3:.1f} mm, |Gamma(0)| {r['gamma_normal_abs'][0]:.2f}{range_words(r)}"
        for r in table[:12])
        + (f" (+{len(table) - 12} more)" if len(table) > 12 else ""))
    return RfFitResult(out_path, num_gaussians, int(len(rows)), freqs.tolist(), result.train_mae_db,
                       result.initial_mae_db, result.steps, time.time() - t_start, trace_s,
                       "off" if not pair_settings.visibility else "traced", timings, selection, table, warnings)


def _timing_attrs(timings: dict) -> dict:
    """Training attributes for the wall times [s]: wall_time_s (the whole command, up to writing the
    artifact), trace_time_s, select_time_s (model selection, every candidate; each candidate's own
    time is in selection_fit_time_<sharing>_s), refit_time_s (the final fit) and ranges_time_s (the
    materials' |Gamma(0)| ranges)."""
    out = {"trace_time_s": float(timings.get("trace", 0.0)), "select_time_s": float(timings.get("select", 0.0)),
           "refit_time_s": float(timings.get("fit", 0.0)), "ranges_time_s": float(timings.get("ranges", 0.0))}
    out["wall_time_s"] = float(timings.get("total", sum(out.values())))
    return out


def _root_attrs(scene, meas, task: str) -> dict:
    attrs = {"task": task, "scene": str(meas.attrs.get("scene", scene.attrs.get("scene", "")))}
    if "label_names" in scene.attrs:
        attrs["label_names"] = np.asarray([str(s) for s in scene.attrs["label_names"]], dtype=object)
    return attrs


def _training_attrs(meas, protocol: str, rows: np.ndarray, selection: dict, seed: int) -> dict:
    """Training attributes every rf artifact records (split, measurements, model selection)."""
    out = {"measurements": str(meas.path), "split": protocol, "split_protocol": describe_split(protocol),
           "seed": seed, "num_train_rows": int(len(rows)),
           "num_test_rows": int(protocol_masks(meas, protocol, str(meas.path))[1].sum())}
    if meas.get("range_m") is not None:
        out["train_ranges_m"] = ", ".join(f"{r:g}" for r in np.unique(np.round(np.asarray(meas["range_m"])[rows], 6)))
    out.update({f"selection_{k}": v for k, v in selection.items()})
    return out
