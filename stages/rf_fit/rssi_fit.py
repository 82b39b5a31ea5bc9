"""`rfir rf-fit` for RSSI measurements (task "rssi"): the LoS/NLoS model of rssi_model.py.

Called by stage.run when the measurement file's task is "rssi". Steps: pick the training rows
(`[rf_fit.rssi] split`: the file's split, or `holdout_tx` transmitters held out at random with the
seed), trace once (probe field for the receivers, V per transmitter, direct-path transmittances),
cache the per-link terms, fit with Adam on mini-batches of links (dB loss), write an `rf` artifact
whose model/ group holds everything predict needs (system gain, NLoS gain, the LoS network's
weights, the probe field, the settings).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import psutil
import torch

from rfir_cli.artifacts import write_artifact
from rfir_cli.errors import ConfigError, InputFileError, StageError
from rfir_cli.progress import NullProgress
from rfir_cli.provenance import Provenance

from .antennas import AntennaPattern
from .fit import loss_fn
from .links import check_overlap, check_positions, geometry_from_artifact, pick_rows
from .occlusion import make_provider
from .rssi_model import (RssiModel, build_probe_field, friis_los, link_terms, los_transmittance, point_transmittance,
                         predict_db, render_los, render_nlos)

CACHE_BYTES = 24  # per link and Gaussian: float32 amplitude and lobe, complex64 phase, + temporaries
RSSI_MODELS = ("free", "physical")
RSSI_DEFAULTS = {"model": "physical", "split": "file", "holdout_tx": 4, "weighting": True, "probe_step_m": 0.5, "hidden": 16,
                 "batch_links": 1024, "los_lr": 0.01, "nlos_init_db": -6.0}


def rssi_settings(config: dict) -> dict:
    """The [rf_fit.rssi] table with defaults filled in and checked."""
    cfg = dict(RSSI_DEFAULTS)
    cfg.update(config.get("rssi", {}) or {})
    if cfg["model"] not in RSSI_MODELS:
        raise ConfigError(f"rf_fit.rssi.model = {cfg['model']!r}: expected one of {', '.join(RSSI_MODELS)}")
    if cfg["split"] not in ("file", "holdout_tx"):
        raise ConfigError(f"rf_fit.rssi.split = {cfg['split']!r}: expected 'file' or 'holdout_tx'")
    if not cfg["probe_step_m"] > 0 or int(cfg["batch_links"]) < 1:
        raise ConfigError("rf_fit.rssi.probe_step_m must be > 0 and rf_fit.rssi.batch_links >= 1")
    return cfg


def holdout_transmitters(tx_id: np.ndarray, count: int, seed: int) -> np.ndarray:
    """`count` distinct transmitter ids drawn at random with `seed` (sorted)."""
    ids = np.unique(tx_id)
    if not 0 < count < len(ids):
        raise ConfigError(f"rf_fit.rssi.holdout_tx = {count}: need 0 < holdout_tx < {len(ids)} transmitters")
    return np.sort(np.random.default_rng(seed).choice(ids, size=count, replace=False))


def training_rows(meas, cfg: dict, seed: int, where: str) -> tuple[np.ndarray, np.ndarray]:
    """(train rows, held-out transmitter ids) per the split protocol."""
    if cfg["split"] == "file":
        return pick_rows(meas.get("split"), 0, where), np.zeros(0, np.int64)
    tx_id = meas.get("tx_id")
    if tx_id is None:
        raise StageError("split 'holdout_tx' needs tx_id in the measurements", path=where)
    held = holdout_transmitters(np.asarray(tx_id), int(cfg["holdout_tx"]), seed)
    return np.flatnonzero(~np.isin(np.asarray(tx_id), held)), held


def unique_rows(points: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    """Distinct points [U, 3] and the index [N] of each input row among them."""
    uniq, inv = np.unique(np.round(np.asarray(points, np.float64), 9), axis=0, return_inverse=True)
    return torch.as_tensor(uniq), torch.as_tensor(inv.reshape(-1), dtype=torch.int64)


def prepare_terms(geom, provider, tx, rx, freq_hz, opacity, margin, t_stop, field, antenna, progress):
    """LinkTerms for links tx / rx [M, 3] (numpy): V per distinct Tx traced, Tbar from the probe field."""
    tx_u, tx_i = unique_rows(tx)
    rx_u, rx_i = unique_rows(rx)
    with progress.task("trace V per transmitter", total=len(tx_u)) as bar:
        v_tx = point_transmittance(provider, geom, tx_u, opacity, margin, t_stop, progress_task=bar)
    tbar = field.at(rx_u)
    los_v = los_transmittance(provider, torch.as_tensor(tx), torch.as_tensor(rx), opacity, margin)
    return link_terms(geom, torch.as_tensor(tx), torch.as_tensor(rx), freq_hz, v_tx, tx_i, tbar, rx_i, los_v, antenna)


def init_levels(terms, model: RssiModel, target: torch.Tensor, nlos_init_db: float) -> None:
    """s_tx_db: median(measured - direct path) [dB]; nlos_gain_db: NLoS median power nlos_init_db below it."""
    with torch.no_grad():
        los_db = 10 * torch.log10(render_los(terms, model).abs() ** 2 + 1e-300)
        model.rf.s_tx_db.fill_(float(torch.median(target - los_db)))
        nlos_db = 10 * torch.log10(render_nlos(terms, model).abs() ** 2 + 1e-300)
        model.nlos_gain_db.fill_(float(torch.median(los_db - nlos_db)) + nlos_init_db)


def fit_rssi(terms, target: torch.Tensor, model: RssiModel, fit_cfg, cfg: dict, progress) -> dict:
    """Adam on mini-batches of `batch_links` links; returns curve and MAEs."""
    gen = torch.Generator().manual_seed(int(fit_cfg.seed))
    names = list(fit_cfg.learn) + ["los", "nlos_gain"]
    groups = model.groups(names)
    lrs = {"s_tx": fit_cfg.s_tx_lr, "nlos_gain": fit_cfg.s_tx_lr, "los": float(cfg["los_lr"])}
    for g in groups:
        g["lr"] = lrs.get(g["name"], fit_cfg.lr)
    opt = torch.optim.Adam(groups)
    with torch.no_grad():
        initial = float((predict_db(terms, model) - target).abs().mean())
    batch = min(int(cfg["batch_links"]), terms.num)
    curve = []
    t0 = time.time()
    with progress.task("rf-fit (rssi)", total=fit_cfg.iterations) as bar:
        for it in range(fit_cfg.iterations):
            idx = torch.randperm(terms.num, generator=gen)[:batch]
            opt.zero_grad()
            loss = loss_fn(predict_db(terms.subset(idx), model), target[idx], fit_cfg.loss, fit_cfg.huber_db)
            if not torch.isfinite(loss):
                raise StageError(f"the RSSI fit diverged (loss {float(loss)} at iteration {it}); lower rf_fit.lr")
            loss.backward()
            opt.step()
            curve.append(float(loss.detach()))
            bar.advance(1)
    with torch.no_grad():
        train_mae = float((predict_db(terms, model) - target).abs().mean())
    return {"curve": np.asarray(curve), "initial_mae_db": initial, "train_mae_db": train_mae,
            "fit_time_s": time.time() - t0}


def run_rssi(scene, meas, scene_path: Path, measurements_path: Path, out_path: Path, config: dict, render_cfg,
             fit_cfg, *, seed: int = 0, config_toml: str = "", progress=None):
    """Fit the RSSI model; see the module docstring. Returns stage.RfFitResult."""
    from .stage import RfFitResult

    progress = progress or NullProgress()
    t_start = time.time()
    cfg = rssi_settings(config)
    if str(config.get("split", "data")) != "data":
        raise ConfigError(f"rf_fit.split = {config['split']!r} is for rcs data; RSSI data uses rf_fit.rssi.split "
                          "('file' or 'holdout_tx')")
    geom = geometry_from_artifact(scene)
    where = str(measurements_path)
    if cfg["model"] == "free" and fit_cfg.sharing == "label" and scene.get("gaussians/labels") is None:
        # checked before any tracing: geometry from photos has no object labels
        progress.log("warning: rf_fit.sharing = 'label' but the scene has no gaussians/labels (geometry from "
                     "photos?): one material for all Gaussians ('global') instead; rf_fit.rssi.model = physical "
                     "fits materials per segment of the geometry")
        fit_cfg.sharing = "global"
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
    target_np = np.asarray(meas["path_gain_db"], np.float64)[rows, col]
    if not np.isfinite(target_np).all():
        raise InputFileError("path_gain_db has non-finite training values", path=measurements_path)
    kind = str(config.get("antenna", "auto"))
    antenna = AntennaPattern("isotropic" if kind == "auto" else kind, hpbw_deg=float(config.get("horn_hpbw_deg", 40.0)))
    if antenna.kind not in ("isotropic", "dipole"):
        raise ConfigError(f"rf_fit.antenna = {kind!r}: the RSSI model takes omni antennas (isotropic or dipole)")
    if cfg["model"] == "physical":   # the physical room model (docs/physics.md section 8.10): room_stage.py
        if antenna.kind != "isotropic":
            raise ConfigError(f"rf_fit.antenna = {kind!r}: the physical room model takes isotropic antennas")
        from .room_stage import run_room
        return run_room(scene, meas, geom, rows, held, tx, rx, float(freqs[col]), target_np, scene_path,
                        measurements_path, out_path, config, render_cfg, cfg, seed=seed, config_toml=config_toml,
                        progress=progress, t_start=t_start)

    need = len(rows) * geom.num * CACHE_BYTES
    avail = psutil.virtual_memory().available
    if need > 0.7 * avail:
        raise StageError(f"{len(rows)} training links x {geom.num} Gaussians need a ~{need / 2**30:.1f} GiB cache, above 70% "
                         f"of the {avail / 2**30:.1f} GiB available; use coarser surfels or rf_fit.max_links")
    t0 = time.time()
    provider = make_provider(str(config.get("occlusion", "auto")), geom, render_cfg.alpha_min)
    opacity = torch.full((geom.num,), fit_cfg.init_opacity, dtype=torch.float64)
    margin, t_stop = render_cfg.self_shadow_margin_m, render_cfg.t_stop
    progress.log(f"rf-fit (rssi): {geom.num} Gaussians, {len(rows)} training links, occlusion {provider.name}, "
                 f"split {cfg['split']}")
    from .rssi_model import lattice_for
    _, shape = lattice_for(geom, float(cfg["probe_step_m"]))
    with progress.task("trace probe field", total=int(np.prod(shape))) as bar:
        field = build_probe_field(provider, geom, float(cfg["probe_step_m"]), opacity, margin, t_stop, bar)
    terms = prepare_terms(geom, provider, tx, rx, float(freqs[col]), opacity, margin, t_stop, field, antenna, progress)
    trace_s = time.time() - t0

    from .params import RFParams
    labels = scene.get("gaussians/labels")
    index = RFParams.sharing_index(fit_cfg.sharing, geom.num, None if labels is None else torch.as_tensor(labels))
    torch.manual_seed(seed)
    model = RssiModel(index, weighting=bool(cfg["weighting"]), hidden=int(cfg["hidden"]), opacity=fit_cfg.init_opacity,
                      roughness=fit_cfg.init_roughness, gamma_abs=fit_cfg.init_gamma_abs,
                      gamma_phase_rad=fit_cfg.init_gamma_phase_rad)
    target = torch.as_tensor(target_np)
    init_levels(terms, model, target, float(cfg["nlos_init_db"]))
    res = fit_rssi(terms, target, model, fit_cfg, cfg, progress)

    prov = Provenance(stage="rf-fit", config_toml=config_toml, device="cpu")
    prov.add_input(scene_path)
    prov.add_input(measurements_path)
    prov.wall_time_s = time.time() - t_start
    prov.extra = {"seed": seed, "train_rows": int(len(rows)), "trace_time_s": trace_s, "occlusion": provider.name,
                  "fit_time_s": res["fit_time_s"]}
    _write(out_path, scene, meas, freqs[col], rows, held, model, field, cfg, render_cfg, fit_cfg, res, trace_s,
           antenna, prov)
    return RfFitResult(out_path, geom.num, int(len(rows)), [float(freqs[col])], res["train_mae_db"],
                       res["initial_mae_db"], fit_cfg.iterations, time.time() - t_start, trace_s, provider.name,
                       {"trace": trace_s, "fit": res["fit_time_s"]})


def _write(out_path, scene, meas, freq, rows, held, model: RssiModel, field, cfg, render_cfg, fit_cfg, res, trace_s,
           antenna, prov) -> None:
    with torch.no_grad():
        mats = model.rf.materials()
    data = {k: v for k, v in scene.data.items() if k.startswith("gaussians/")}
    data.update({"rf/opacity": mats.opacity.numpy(), "rf/roughness": mats.roughness.numpy(),
                 "rf/gamma_abs": mats.gamma.abs().numpy(), "rf/gamma_phase_rad": np.angle(mats.gamma.numpy()),
                 "rf/freq_hz": np.asarray([freq], np.float64)})
    model_data = {"s_tx_db": model.rf.s_tx_db.detach().numpy().copy(),
                  "nlos_gain_db": model.nlos_gain_db.detach().reshape(1).numpy().copy(),
                  "probe_values": field.values.numpy(), "probe_origin_m": np.asarray(field.origin, np.float64),
                  "probe_shape": np.asarray(field.shape, np.int64)}
    for name, p in model.los.state_dict().items():
        model_data["los." + name] = p.detach().numpy().copy()
    model_attrs = {"model_kind": "rssi_los_nlos", "renderer": "rfir_stages.rf_fit.rssi_model (docs/physics.md section 6)",
                   "weighting": bool(cfg["weighting"]), "hidden": int(cfg["hidden"]),
                   "probe_step_m": float(field.step_m), "render.self_shadow_margin_m": render_cfg.self_shadow_margin_m,
                   "render.t_stop": render_cfg.t_stop, "render.alpha_min": render_cfg.alpha_min,
                   "render.visibility_opacity": fit_cfg.init_opacity}
    model_attrs.update(antenna.describe())
    training_attrs = {"loss": fit_cfg.loss, "iterations": fit_cfg.iterations, "lr": fit_cfg.lr,
                      "sharing": fit_cfg.sharing, "learn": ",".join(fit_cfg.learn), "seed": fit_cfg.seed,
                      "train_mae_db": res["train_mae_db"], "initial_mae_db": res["initial_mae_db"],
                      "wall_time_s": prov.wall_time_s, "fit_time_s": res["fit_time_s"], "trace_time_s": trace_s,
                      "batch_links": int(cfg["batch_links"]),
                      "measurements": str(meas.path), "split": cfg["split"],
                      "split_protocol": ("rows with split == 0 (train)" if cfg["split"] == "file" else
                                         f"transmitters {held.tolist()} held out (seed {fit_cfg.seed})")}
    attrs = {"task": "rssi", "scene": str(meas.attrs.get("scene", scene.attrs.get("scene", "")))}
    if "label_names" in scene.attrs:
        attrs["label_names"] = np.asarray([str(s) for s in scene.attrs["label_names"]], dtype=object)
    free = {"model": {**model_data, "@attrs": model_attrs},
            "training": {"loss_curve": res["curve"], "train_rows": np.asarray(rows, np.int64),
                         "holdout_tx_ids": np.asarray(held, np.int64), "@attrs": training_attrs}}
    write_artifact(out_path, "rf", data, attrs=attrs, provenance=prov, free=free)


def friis_check_db(dist_m: np.ndarray, freq_hz: float) -> np.ndarray:
    """Free-space path gain [dB] at distances [M] m (for tests and docs)."""
    return 20 * np.log10(np.abs(friis_los(torch.as_tensor(dist_m, dtype=torch.float64), freq_hz).numpy()))
