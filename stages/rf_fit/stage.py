"""`rfir rf-fit`: per-Gaussian radio materials fitted to the training split of a measurement file.

run(scene.h5, measurements.h5, rf.h5, config) reads a `scene` (or `rf`) artifact and a
`measurements` artifact, traces once (the cache), fits with Adam and writes an `rf` artifact:
the scene's Gaussians, rf/opacity, rf/roughness, rf/gamma_abs, rf/gamma_phase_rad, rf/freq_hz;
group model/ (system gain per frequency and the renderer settings predict must reuse, as
attributes) and group training/ (loss curve, training rows, MAEs).
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from rfir_cli.artifacts import read_artifact, write_artifact
from rfir_cli.errors import ConfigError, InputFileError
from rfir_cli.progress import NullProgress
from rfir_cli.provenance import Provenance
from rfir_stages.model.band import aggregate_chunk

from .antennas import antenna_choice
from .fit import FLOOR_DB, FitConfig, FitResult, fit, mae_db, predict_db
from .unseen import fill_unseen, unseen_mask
from .links import check_overlap, check_positions, geometry_from_artifact, make_links, pick_freqs, scene_centre
from .occlusion import make_provider
from .params import RFParams
from .physical_stage import (PhysicalSetup, bound_warnings, material_table, physical_artifact_fields, physical_config,
                             residual_training_attrs, sharing_candidates)
from .render import LinkSet, RenderSettings, build_cache
from .splits import describe as describe_split
from .splits import protocol_masks, split_rows, validation_folds
from .splits import MIN_VALIDATION_LINKS
from .wideband_stage import band_config, is_wideband_request

MODELS = ("auto", "free", "physical")
SCATTERING = ("auto", "coherent", "incoherent")
SHARING = ("auto", "gaussian", "label", "global")
SHARING_AUTO = ("gaussian", "global")   # the candidates of sharing = "auto" (RCS fits)
RENDER_KEYS = ("visibility", "grid_step_deg", "center_ray_cells", "self_shadow_margin_m", "alpha_min",
               "colocated_tol_m", "learn_visibility", "t_stop", "path_loss", "phase")
FIT_KEYS = ("iterations", "lr", "s_tx_lr", "loss", "huber_db", "learn", "init_opacity", "init_roughness",
            "init_gamma_abs", "init_gamma_phase_rad", "sharing", "checkpoint_every", "diffuse", "init_diffuse",
            "init_diffuse_roughness")


@dataclass
class RfFitResult:
    """Summary of one rf-fit run."""

    path: Path
    num_gaussians: int
    num_train_links: int
    freqs_hz: list
    train_mae_db: float
    initial_mae_db: float
    iterations: int
    wall_time_s: float
    trace_time_s: float
    occlusion: str
    timings_s: dict = field(default_factory=dict)
    scattering: dict = field(default_factory=dict)   # requested / selected model, validation MAEs
    materials: list = field(default_factory=list)    # physical model: one dict per fitted material
    warnings: list = field(default_factory=list)


def settings_from_config(cfg: dict) -> tuple[RenderSettings, FitConfig]:
    """RenderSettings and FitConfig from the [rf_fit] table (unknown keys were refused upstream)."""
    render = RenderSettings(**{k: cfg[k] for k in RENDER_KEYS if k in cfg})
    fit_kw = {k: cfg[k] for k in FIT_KEYS if k in cfg}
    if "learn" in fit_kw:
        fit_kw["learn"] = tuple(fit_kw["learn"])
    return render, FitConfig(**fit_kw)


def _key(*parts) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def run(scene_path, measurements_path, out_path, config: dict, *, seed: int = 0, config_toml: str = "",
        progress=None, checkpoint: Path | None = None, resume: bool = False, select=None,
        t_start: float | None = None) -> RfFitResult:
    """Fit RF attributes; see the module docstring. config: the [rf_fit] table. select: a
    rfir_stages.importers.select.RowSelection of ranges / aspects narrowing the training rows."""
    progress = progress or NullProgress()
    t_start = time.time() if t_start is None else t_start   # when the command began: the wall time covers it all
    scene_path, measurements_path, out_path = Path(scene_path), Path(measurements_path), Path(out_path)
    if out_path.resolve() in (scene_path.resolve(), measurements_path.resolve()):
        raise ConfigError(f"-o {out_path} would overwrite an input")
    torch.manual_seed(seed)
    render_cfg, fit_cfg = settings_from_config(config)
    fit_cfg.seed = seed
    render_cfg.visibility_opacity = fit_cfg.init_opacity
    scene = read_artifact(scene_path, ("scene", "rf"))
    meas = read_artifact(measurements_path, "measurements")
    task = str(meas.attrs.get("task", ""))
    ant = antenna_choice(config, meas, task, str(measurements_path))
    progress.log(f"rf-fit: {ant.note()}")
    if "polarisation" in meas.attrs:   # the physical model uses what the measurements state
        phys = dict(config.get("physical") or {})
        if str(phys.get("polarisation", "V")).upper() != meas.attrs["polarisation"]:
            progress.log(f"rf-fit: polarisation {meas.attrs['polarisation']} (stated by the measurements; "
                         f"rf_fit.physical.polarisation {phys.get('polarisation', 'V')} not used)")
        config = dict(config, physical=dict(phys, polarisation=str(meas.attrs["polarisation"])))
    if fit_cfg.sharing not in SHARING:
        raise ConfigError(f"rf_fit.sharing = {fit_cfg.sharing!r}: expected one of {', '.join(SHARING)}")
    sharing_requested = fit_cfg.sharing
    if fit_cfg.sharing == "auto" and (task == "rssi" or is_wideband_request(task, config)):
        fit_cfg.sharing = "gaussian"   # the choice by validation is made for narrowband RCS fits only
    if task == "rssi":  # the LoS/NLoS model (docs/physics.md section 6): stages/rf_fit/rssi_fit.py
        from .rssi_fit import run_rssi
        if resume:
            raise ConfigError("--resume: RSSI fits write no checkpoints yet")
        if select:
            raise ConfigError("--range / --aspects select rows of rcs or wideband measurements, not of rssi ones")
        config = dict(config, antenna=ant.kind)   # what the measurements state (or isotropic, said above)
        return run_rssi(scene, meas, scene_path, measurements_path, out_path, config, render_cfg, fit_cfg, seed=seed,
                        config_toml=config_toml, progress=progress)
    geom = geometry_from_artifact(scene)
    check_overlap(geom, meas, str(measurements_path))
    model_kind = str(config.get("model", "auto"))
    if model_kind not in MODELS:
        raise ConfigError(f"rf_fit.model = {model_kind!r}: expected one of {', '.join(MODELS)}")
    mode = str(config.get("scattering", "auto"))
    if mode not in SCATTERING:
        raise ConfigError(f"rf_fit.scattering = {mode!r}: expected one of {', '.join(SCATTERING)}")
    if mode != "coherent" and not fit_cfg.diffuse:
        raise ConfigError(f"rf_fit.scattering = {mode!r} needs rf_fit.diffuse = true (the incoherent term)")
    protocol = str(config.get("split", "data"))
    rows, test_rows = split_rows(meas, protocol, str(measurements_path))
    if select:
        from rfir_stages.importers.select import select_rows
        rows, _ = select_rows(meas, select, str(measurements_path), rows)
        progress.log(f"rf-fit: {select.describe()} keeps {len(rows)} training rows")
    band_attrs = {}
    if is_wideband_request(task, config):  # docs/wideband.md: the physical model on the band
        config, band_attrs = band_config(config, meas, str(measurements_path), progress)
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

    model_kind = str(config.get("model", "auto"))   # "physical" after band_config
    labels = scene.get("gaussians/labels")
    labels = None if labels is None else torch.as_tensor(np.asarray(labels))
    phys_cfg, pair_settings, phys_table = physical_config(config, render_cfg)
    num_labels = 0 if labels is None else int(torch.unique(labels).numel())
    phys_sharings = sharing_candidates(phys_table, num_labels) if model_kind != "free" else []
    if phys_sharings == ["global"] and str(phys_table.get("sharing", "auto")) == "auto":
        progress.log("rf-fit: one object label: its material is the scene's (rf_fit.physical.sharing = auto -> global)")
    t0 = time.time()
    provider = make_provider(str(config.get("occlusion", "auto")), geom, render_cfg.alpha_min) \
        if render_cfg.visibility else None
    progress.log(f"rf-fit: {geom.num} Gaussians, {links.num} training links x {len(freqs)} frequencies, "
                 f"occlusion {getattr(provider, 'name', 'off')}, antenna {ant.kind}, model {model_kind}"
                 + (f" (physical: polarisation {pair_settings.polarisation}, sigma ~ f^{phys_cfg.sigma_exponent:g}, "
                    f"double bounces {'on' if pair_settings.second_order else 'off'}, "
                    f"system gain {'fitted' if phys_cfg.fit_gain else '0 dB'})" if phys_sharings else ""))
    cache = physical = None
    if model_kind != "physical":
        with progress.task("trace (cache)", total=1) as bar:
            cache = build_cache(geom, links, ant, ant, provider, render_cfg)
            bar.advance(1)
    if phys_sharings:
        with progress.task("trace (physical pairs)", total=1) as bar:
            names = [str(n) for n in scene.attrs["label_names"]] if "label_names" in scene.attrs else None
            physical = PhysicalSetup.trace(geom, links, ant, provider, pair_settings, labels, phys_table, seed, names)
            if band_attrs:   # many frequencies: aggregate in smaller pair chunks; the band goes into the artifact
                physical.agg_chunk, physical.extra_attrs = aggregate_chunk(len(freqs)), band_attrs
            bar.advance(1)
    trace_s = time.time() - t0

    candidates = [] if model_kind == "physical" else \
        [(m, s) for m in (("coherent", "incoherent") if mode == "auto" else (mode,))
         for s in (SHARING_AUTO if fit_cfg.sharing == "auto" else (fit_cfg.sharing,))]
    candidates += [("physical", s) for s in phys_sharings]
    scattering = {"requested": mode, "selected": candidates[0][0], "sharing_requested": sharing_requested,
                  "sharing_selected": candidates[0][1], "model_requested": model_kind}
    # A checkpoint fits any run with the same inputs, rows and settings; more iterations may follow it.
    key = _key(str(scene_path.resolve()), str(measurements_path.resolve()),
               {k: v for k, v in config.items() if k not in ("iterations", "checkpoint_every")}, seed,
               np.asarray(rows).tolist())
    ckpt = Path(checkpoint) if checkpoint is not None else out_path.with_name(out_path.name + ".ckpt.pt")
    chosen = ckpt.with_name(ckpt.name + ".selection")   # the model selection of this run, for --resume
    t_sel = time.time()
    reused = _load_selection(chosen, key) if resume and len(candidates) > 1 else None
    if reused is not None:
        scattering = reused
        progress.log(f"rf-fit: model selection reused from {chosen}: {scattering['selected']}/"
                     f"{scattering['sharing_selected']}")
    elif len(candidates) > 1:
        asp, rng = meas.get("aspect_rad"), meas.get("range_m")
        folds, how = validation_folds(protocol, None if asp is None else np.degrees(np.asarray(asp)[rows]),
                                      None if rng is None else np.asarray(rng)[rows])
        scattering.update(_select_model(geom, links, target, folds, how, ant, provider, render_cfg, candidates,
                                        labels, fit_cfg, progress, physical, phys_cfg))
        _save_selection(chosen, key, scattering)
    select_s = time.time() - t_sel
    starts = scattering.pop("states", [])   # the selected candidate's fitted states: where the refit starts
    warnings = [scattering.pop("warning")] if "warning" in scattering else []
    scattering["model_selected"] = "physical" if scattering["selected"] == "physical" else "free"
    if scattering["selected"] == "physical":
        return _run_physical(physical, scattering, target, phys_cfg, pair_settings, scene, meas, task, freqs, rows,
                             ant, protocol, scene_path, measurements_path, out_path, config_toml, seed, progress,
                             t_start, trace_s, select_s, geom.num, starts, warnings)
    fit_cfg.sharing = scattering["sharing_selected"]
    index = RFParams.sharing_index(fit_cfg.sharing, geom.num, labels)
    params = _new_params(index, len(freqs), fit_cfg, coherent=scattering["selected"] == "coherent")
    warm = _best_start(cache, target, params, starts)
    result = fit(cache, target, params, fit_cfg, progress=progress, checkpoint=ckpt, resume=resume, key=key,
                 init_gain=not warm)
    if result.extra.get("floored"):
        warnings.append(f"{result.extra['floored']} of {target.size} predicted training path gains are at the "
                        f"prediction floor ({FLOOR_DB:g} dB): links that see no Gaussian")
    if bool(config.get("fill_unseen", True)) and fit_cfg.sharing == "gaussian" and "exposure" in result.extra:
        unseen = unseen_mask(result.extra["exposure"])
        result.extra["unseen_filled"] = fill_unseen(result, unseen, geom.means.numpy(),
                                                    None if labels is None else np.asarray(labels))
        progress.log(f"rf-fit: {result.extra['unseen_filled']} Gaussians no training link sees took their "
                     "neighbours' materials")

    for w in warnings:
        progress.log(f"warning: {w}")
    timings = {"trace": trace_s, "select": select_s, "fit": result.wall_time_s, "total": time.time() - t_start}
    prov = Provenance(stage="rf-fit", config_toml=config_toml, device="cpu")
    prov.add_input(scene_path)
    prov.add_input(measurements_path)
    prov.wall_time_s = timings["total"]
    prov.extra = {"seed": seed, "train_rows": int(len(rows)), "trace_time_s": trace_s,
                  "occlusion": getattr(provider, "name", "off"), "fit_time_s": result.wall_time_s,
                  "scattering_selection_time_s": select_s}
    _write(out_path, scene, meas, task, freqs, rows, result, ant, render_cfg, fit_cfg, prov, trace_s, protocol,
           scattering, timings, warnings)
    return RfFitResult(out_path, geom.num, int(len(rows)), freqs.tolist(), result.train_mae_db,
                       result.initial_mae_db, result.iterations, time.time() - t_start, trace_s,
                       getattr(provider, "name", "off"), timings, scattering, warnings=warnings)


def _new_params(index: torch.Tensor, num_freqs: int, fit_cfg: FitConfig, coherent: bool) -> RFParams:
    return RFParams(index, num_freqs, opacity=fit_cfg.init_opacity, roughness=fit_cfg.init_roughness,
                    gamma_abs=fit_cfg.init_gamma_abs, gamma_phase_rad=fit_cfg.init_gamma_phase_rad,
                    diffuse=fit_cfg.init_diffuse if fit_cfg.diffuse else None,
                    diffuse_roughness=fit_cfg.init_diffuse_roughness, coherent=coherent)


def _save_selection(path: Path, key: str, scattering: dict) -> None:
    """The model selection's outcome (and the free candidates' fitted states) beside the checkpoint,
    written to a temporary file and renamed, so `--resume` after a kill does not select again."""
    states = scattering.get("states", [])
    record = {"key": key, "scattering": {k: v for k, v in scattering.items() if k != "states"},
              "states": states if states and isinstance(states[0], dict) else []}   # physical fits: refit anyway
    tmp = path.with_name(path.name + ".partial")
    torch.save(record, tmp)
    tmp.replace(path)


def _load_selection(path: Path, key: str) -> dict | None:
    """The saved selection (scattering dict with "states") when it was made for the same run, else None."""
    if not path.exists():
        return None
    try:
        record = torch.load(path, weights_only=True)
    except Exception as exc:  # noqa: BLE001 - a damaged record is a user-fixable input problem
        raise InputFileError(f"cannot read the saved model selection ({exc}); delete it", path=path) from None
    if record.get("key") != key:
        return None
    return dict(record["scattering"], states=record["states"])


def _best_start(cache, target: np.ndarray, params: RFParams, states: list) -> bool:
    """Load into `params` the state (of `states`, the selected candidate's fits) that predicts every
    training link [M, K] best, so the refit starts from it and (keeping its best state) never ends
    worse. Returns whether a state was loaded."""
    best = None
    for state in states:
        params.load_state_dict(state)
        with torch.no_grad():
            err = mae_db(predict_db(cache, params).numpy(), target)
        if best is None or err < best[0]:
            best = (err, state)
    if best is not None:
        params.load_state_dict(best[1])
    return best is not None


def _subset(links: LinkSet, idx: np.ndarray) -> LinkSet:
    i = torch.as_tensor(idx)
    return LinkSet(links.tx_m[i], links.rx_m[i], links.freq_hz, links.tx_axis[i], links.rx_axis[i])


def _select_model(geom, links: LinkSet, target: np.ndarray, folds: list[np.ndarray], how: str, ant, provider,
                  render_cfg: RenderSettings, candidates: list[tuple[str, str]], labels: torch.Tensor | None,
                  fit_cfg: FitConfig, progress, physical: PhysicalSetup | None = None, phys_cfg=None) -> dict:
    """The (scattering, sharing) candidate that predicts held-out training rows best after the same
    fit on the rest: scattering "coherent" (coherent sum + diffuse term) or "incoherent" (the diffuse
    term alone); sharing "gaussian" (a material per Gaussian) or "global" (one for the scene), say.
    `folds`: lists of training rows held out in turn, shaped like the protocol's test by
    splits.validation_folds; the test split is never looked at. A free candidate keeps, in each
    fold, its state of lowest validation MAE (not the last step); its score pools every fold's
    held-out links. Fewer than 10 training links: the first candidate. Candidates ("physical",
    sharing) fit the physical model (physical_stage.py) on the same rows.
    Returns {"selected", "sharing_selected", "validation_links", "validation", "val_mae_<...>_db",
    "fit_time_<...>_s", "states"} ("states": the selected candidate's fitted parameters per fold)."""
    m = links.num
    val_all = np.concatenate(folds) if folds else np.zeros(0, np.int64)
    if m < 10 or len(val_all) == 0 or any(len(f) in (0, m) for f in folds):
        progress.log(f"rf-fit: choosing the model by validation needs >= 10 training links and a validation set "
                     f"(got {m}); using {' / '.join(candidates[0])}")
        return {"why": "too few training links to validate"}
    out = {"validation_links": int(len(val_all)), "validation": how, "validation_folds": len(folds)}
    if len(val_all) < MIN_VALIDATION_LINKS:
        out["warning"] = (f"the model was chosen on {len(val_all)} validation links (< {MIN_VALIDATION_LINKS}): "
                          "the choice may be noise; more training rows make it firmer")
        progress.log(f"warning: {out['warning']}")
    caches = [None] * len(folds)
    several_sharings = len({s for _, s in candidates}) > 1
    scores, states = {}, {}
    for mode, sharing in candidates:
        t0 = time.time()
        pred = np.zeros((len(val_all), target.shape[1]))
        states[mode, sharing] = []
        at = 0
        for j, val in enumerate(folds):
            fit_rows = np.setdiff1d(np.arange(m), val)
            if mode == "physical":
                res = physical.fit(sharing, fit_rows, target[fit_rows], phys_cfg, progress)
                pred[at:at + len(val)] = physical.predict_db(sharing, val, res.params)
                states[mode, sharing].append(res)
            else:
                if caches[j] is None:
                    caches[j] = (build_cache(geom, _subset(links, fit_rows), ant, ant, provider, render_cfg),
                                 build_cache(geom, _subset(links, val), ant, ant, provider, render_cfg))
                index = RFParams.sharing_index(sharing, geom.num, labels)
                params = _new_params(index, target.shape[1], fit_cfg, coherent=mode == "coherent")
                fit(caches[j][0], target[fit_rows], params, fit_cfg, progress=progress,
                    validation=(caches[j][1], target[val]))
                with torch.no_grad():
                    pred[at:at + len(val)] = predict_db(caches[j][1], params).numpy()
                states[mode, sharing].append(params.state_dict())
            at += len(val)
        name = f"{mode}_{sharing}" if several_sharings else mode
        scores[mode, sharing] = mae_db(pred, target[val_all])
        out[f"val_mae_{name}_db"] = scores[mode, sharing]
        out[f"fit_time_{name}_s"] = time.time() - t0
    out["selected"], out["sharing_selected"] = min(candidates, key=scores.get)
    out["states"] = states[out["selected"], out["sharing_selected"]]
    progress.log(f"rf-fit: validation MAE on {len(val_all)} held-out training links ({how}): "
                 + ", ".join(f"{m}/{s} {v:.2f} dB" for (m, s), v in scores.items())
                 + f" -> {out['selected']}/{out['sharing_selected']}")
    return out


def _write(out_path, scene, meas, task, freqs, rows, result: FitResult, ant, render_cfg: RenderSettings,
           fit_cfg: FitConfig, prov, trace_s, protocol: str = "data", scattering: dict | None = None,
           timings: dict | None = None, warnings: list | None = None) -> None:
    data = {k: v for k, v in scene.data.items() if k.startswith("gaussians/")}
    data.update({
        "rf/opacity": result.opacity, "rf/roughness": result.roughness, "rf/gamma_abs": result.gamma_abs,
        "rf/gamma_phase_rad": result.gamma_phase_rad, "rf/freq_hz": np.asarray(freqs, dtype=np.float64),
    })
    model_attrs = {"s_tx_db_doc": "system gain |S_tx(f)|^2 per rf/freq_hz [dB], added to 10 log10 |S|^2",
                   "renderer": "rfir_stages.rf_fit.render (docs/physics.md sections 4-5)"}
    model_attrs.update(ant.describe())
    model_attrs.update({f"render.{k}": getattr(render_cfg, k) for k in RENDER_KEYS + ("visibility_opacity",)})
    training_attrs = _training_attrs(meas, protocol, rows, scattering, fit_cfg.seed)
    training_attrs.update({"loss": fit_cfg.loss, "iterations": fit_cfg.iterations, "lr": fit_cfg.lr,
                           "sharing": fit_cfg.sharing, "learn": ",".join(fit_cfg.learn),
                           "train_mae_db": result.train_mae_db, "initial_mae_db": result.initial_mae_db,
                           "resumed_at": result.resumed_at, "best_step": int(result.extra.get("best_step", 0)),
                           "floored_links": int(result.extra.get("floored", 0)),
                           "unseen_filled": int(result.extra.get("unseen_filled", 0)),
                           "warnings": "; ".join(warnings or [])})
    training_attrs.update(_timing_attrs(timings or {"trace": trace_s, "fit": result.wall_time_s}))
    attrs = _root_attrs(scene, meas, task)
    model = {"s_tx_db": result.s_tx_db, "@attrs": model_attrs}
    if result.diffuse is not None:  # the incoherent term (docs/rf-model.md "Diffuse term")
        model.update(diffuse_abs=result.diffuse, diffuse_roughness=result.diffuse_roughness)
    free = {"model": model,
            "training": {"loss_curve": result.loss_curve, "train_rows": np.asarray(rows, dtype=np.int64),
                         "@attrs": training_attrs}}
    write_artifact(out_path, "rf", data, attrs=attrs, provenance=prov, free=free)


def _run_physical(physical: PhysicalSetup, scattering: dict, target: np.ndarray, phys_cfg, pair_settings, scene, meas,
                  task: str, freqs: np.ndarray, rows: np.ndarray, ant, protocol: str, scene_path: Path,
                  measurements_path: Path, out_path: Path, config_toml: str, seed: int, progress, t_start: float,
                  trace_s: float, select_s: float, num_gaussians: int, starts: list | None = None,
                  warnings: list | None = None) -> RfFitResult:
    """Refit the selected physical candidate on every training link and write the rf artifact.
    starts: the candidate's fits in model selection (PhysicalFitResult per fold); when one of them
    predicts every training link better than the refit, it is kept (a refit never ends worse)."""
    sharing = scattering["sharing_selected"]
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
    _, _, names = physical.for_sharing(sharing)
    table = material_table(result, names, freqs)
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
    model_attrs.update(ant.describe())
    training_attrs = _training_attrs(meas, protocol, rows, scattering, seed)
    training_attrs.update({"loss": phys_cfg.loss, "iterations": phys_cfg.iterations, "lr": phys_cfg.lr,
                           "sharing": sharing, "train_mae_db": result.train_mae_db,
                           "initial_mae_db": result.initial_mae_db, "start_material": result.start,
                           "warnings": "; ".join(warnings)})
    training_attrs.update(residual_training_attrs(residual))
    timings = {"trace": trace_s, "select": select_s, "fit": refit_s, "residual": residual.wall_time_s,
               "total": time.time() - t_start}
    training_attrs.update(_timing_attrs(timings))
    prov = Provenance(stage="rf-fit", config_toml=config_toml, device="cpu")
    prov.add_input(scene_path)
    prov.add_input(measurements_path)
    prov.wall_time_s = timings["total"]
    prov.extra = {"seed": seed, "train_rows": int(len(rows)), "trace_time_s": trace_s,
                  "fit_time_s": refit_s, "scattering_selection_time_s": select_s}
    free = {"model": {"@attrs": model_attrs},
            "training": {"loss_curve": result.loss_curve, "train_rows": np.asarray(rows, dtype=np.int64),
                         "@attrs": training_attrs}}
    write_artifact(out_path, "rf", data, attrs=_root_attrs(scene, meas, task), provenance=prov, free=free)
    progress.log("rf-fit: materials " + "; ".join(
        f"{r['material']}: eps_r {r['eps_r']:.2f}, sigma {r['sigma_s_per_m']:.3g} S/m, S {r['scattering']:.2f}, "
        f"d {r['thickness_m'] * 1e3:.1f} mm, |Gamma(0)| {r['gamma_normal_abs'][0]:.2f}" for r in table[:12])
        + (f" (+{len(table) - 12} more)" if len(table) > 12 else ""))
    return RfFitResult(out_path, num_gaussians, int(len(rows)), freqs.tolist(), result.train_mae_db,
                       result.initial_mae_db, phys_cfg.iterations, time.time() - t_start, trace_s,
                       "off" if not pair_settings.visibility else "traced", timings, scattering, table, warnings)


def _timing_attrs(timings: dict) -> dict:
    """Training attributes for the wall times [s]: wall_time_s (the whole command, up to writing the
    artifact), trace_time_s, select_time_s (model selection, every candidate; each candidate's own
    time is in scattering_fit_time_<candidate>_s) and refit_time_s (the final fit)."""
    out = {"trace_time_s": float(timings.get("trace", 0.0)), "select_time_s": float(timings.get("select", 0.0)),
           "refit_time_s": float(timings.get("fit", 0.0))}
    out["wall_time_s"] = float(timings.get("total", sum(out.values())))
    return out


def _root_attrs(scene, meas, task: str) -> dict:
    attrs = {"task": task, "scene": str(meas.attrs.get("scene", scene.attrs.get("scene", "")))}
    if "label_names" in scene.attrs:
        attrs["label_names"] = np.asarray([str(s) for s in scene.attrs["label_names"]], dtype=object)
    return attrs


def _training_attrs(meas, protocol: str, rows: np.ndarray, scattering: dict | None, seed: int) -> dict:
    """Training attributes every rf artifact records (split, measurements, model selection)."""
    out = {"measurements": str(meas.path), "split": protocol, "split_protocol": describe_split(protocol),
           "seed": seed, "num_train_rows": int(len(rows)),
           "num_test_rows": int(protocol_masks(meas, protocol, str(meas.path))[1].sum())}
    if meas.get("range_m") is not None:
        out["train_ranges_m"] = ", ".join(f"{r:g}" for r in np.unique(np.round(np.asarray(meas["range_m"])[rows], 6)))
    out.update({f"scattering_{k}": v for k, v in (scattering or {"selected": "coherent"}).items()})
    return out
