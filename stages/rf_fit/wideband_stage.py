"""`rfir rf-fit` for wideband measurements (task "wideband" or rf_fit.wideband.enabled = true).

Reads the scene and the measurements, traces the training links once, fits the base model and
the modulation network (wideband_fit.py) over every frequency of the file (or rf_fit.freqs_hz)
and writes an `rf` artifact:
- rf/* : the base materials (frequency-independent), rf/freq_hz: the fitted frequencies;
- model/ : s_tx_db [F] (s_tx(f) at rf/freq_hz, for readers that know only narrowband models),
  the network and s_tx knots as datasets `wideband.<state_dict name>`, attributes
  `wideband = 1`, `wideband.f_min_hz`, `wideband.f_max_hz` (the band predict accepts),
  `wideband.<config key>` and the renderer settings (`render.*`) as rf-fit writes them;
- training/ : loss curves of both steps, training rows, MAEs and timings.
With rf_fit.wideband.save_base = true, OUT_base.h5 holds the step-1 model alone (network off)
for the ablation.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from rfir_cli.artifacts import write_artifact
from rfir_cli.errors import ConfigError, InputFileError
from rfir_cli.progress import NullProgress
from rfir_cli.provenance import Provenance

from .antennas import antenna_choice
from .links import check_positions, make_links, pick_freqs, scene_centre
from .occlusion import make_provider
from .params import RFParams
from .render import build_cache
from .wideband import WidebandModel, pairs_from_cache
from .wideband_fit import WB_KEYS, WidebandConfig, fit_wideband

STATE_PREFIX = "wideband."


def is_wideband_request(task: str, config: dict) -> bool:
    """True when rf-fit should run the wideband fit."""
    return task == "wideband" or bool((config.get("wideband") or {}).get("enabled", False))


def band_model(config: dict, progress) -> str:
    """The model a wideband fit uses: rf_fit.model (checked by the caller), or for "auto"
    rf_fit.wideband.auto_model (printed): "physical" (rfir_stages.model on the band, docs/wideband.md)
    or "free" (this module's family)."""
    kind = str(config.get("model", "auto"))
    if kind == "auto":
        kind = WidebandConfig.from_table(config.get("wideband")).auto_model
        progress.log(f"rf-fit (wideband): rf_fit.model = auto -> {kind} (rf_fit.wideband.auto_model; docs/wideband.md)")
    return kind


def band_config(config: dict, meas, where: str, progress) -> tuple[dict, dict]:
    """(the [rf_fit] table for the physical model on the band, the band's model attributes).

    The materials are fitted on rf_fit.wideband.fit_freqs evenly spaced frequencies of the band
    (rfir_stages.model.band.fit_columns; the band: every measured frequency, or rf_fit.freqs_hz);
    prediction evaluates any frequency. The residual is defined per fitted frequency, so a band fit
    has none (said when one was asked for)."""
    from rfir_stages.model.band import fit_columns

    wb = WidebandConfig.from_table(config.get("wideband"))
    f_all = np.asarray(meas["freq_hz"], np.float64)
    band = f_all[pick_freqs(f_all, config.get("freqs_hz"), where)]
    fit = band[fit_columns(len(band), wb.fit_freqs)]
    phys = dict(config.get("physical") or {})
    if str(phys.get("residual", "auto")) != "off":
        progress.log(f"rf-fit (wideband): rf_fit.physical.residual = {phys.get('residual', 'auto')!r} not used: the "
                     "residual is defined per fitted frequency; the band is fitted by the physical model alone")
    progress.log(f"rf-fit (wideband): physical model on {len(band)} frequencies ({band.min() / 1e9:.4f}-"
                 f"{band.max() / 1e9:.4f} GHz); materials fitted on {len(fit)} of them, evenly spaced "
                 "(rf_fit.wideband.fit_freqs); predict evaluates every frequency")
    attrs = {"band.f_min_hz": float(band.min()), "band.f_max_hz": float(band.max()), "band.num_freqs": int(len(band)),
             "band.fit_freqs": int(len(fit))}
    return dict(config, model="physical", freqs_hz=[float(x) for x in fit], physical=dict(phys, residual="off")), attrs


def run_wideband(scene, meas, geom, scene_path: Path, measurements_path: Path, out_path: Path, config: dict,
                 render_cfg, fit_cfg, *, rows: np.ndarray, seed: int, config_toml: str, progress=None,
                 t_start: float | None = None):
    """Fit and write (see the module docstring). scene / meas: loaded artifacts; geom: FrozenGeometry;
    render_cfg / fit_cfg: from stage.settings_from_config; rows: training rows (the split protocol's).
    Returns stage.RfFitResult."""
    from .stage import RENDER_KEYS, RfFitResult  # late: stage imports this module

    progress = progress or NullProgress()
    t_start = t_start or time.time()
    wb = WidebandConfig.from_table(config.get("wideband"))
    if render_cfg.learn_visibility:
        raise ConfigError("rf_fit.learn_visibility = true is not supported by the wideband fit; set it to false")
    task = str(meas.attrs.get("task", ""))
    cols = pick_freqs(meas["freq_hz"], config.get("freqs_hz"), str(measurements_path))
    tx, rx = meas["tx_pos"][rows], meas["rx_pos"][rows]
    check_positions(geom, np.concatenate([tx, rx]), str(measurements_path), float(config.get("min_clearance_m", 0.02)))
    target = np.asarray(meas["path_gain_db"], dtype=np.float64)[np.ix_(rows, cols)]
    if not np.isfinite(target).all():
        raise InputFileError("path_gain_db has non-finite training values", path=measurements_path)
    freqs = np.asarray(meas["freq_hz"], dtype=np.float64)[cols]
    max_links = int(config.get("max_links", 0))
    if max_links and len(rows) > max_links:
        keep = np.linspace(0, len(rows) - 1, max_links).round().astype(int)
        rows, tx, rx, target = rows[keep], tx[keep], rx[keep], target[keep]
    links = make_links(tx, rx, freqs[:1], scene_centre(geom), task)
    ant = antenna_choice(config, meas, task, str(measurements_path))   # printed by stage.run

    t0 = time.time()
    provider = make_provider(str(config.get("occlusion", "auto")), geom, render_cfg.alpha_min) \
        if render_cfg.visibility else None
    progress.log(f"rf-fit (wideband): {geom.num} Gaussians, {links.num} training links x {len(freqs)} frequencies "
                 f"({freqs.min() / 1e9:.4f}-{freqs.max() / 1e9:.4f} GHz), occlusion {getattr(provider, 'name', 'off')}")
    with progress.task("trace (cache)", total=1) as bar:
        cache = build_cache(geom, links, ant, ant, provider, render_cfg)
        pairs = pairs_from_cache(cache, wb.pair_floor)
        del cache
        bar.advance(1)
    trace_s = time.time() - t0
    progress.log(f"rf-fit (wideband): {pairs.link.numel()} contributing link-Gaussian pairs")

    labels = scene.get("gaussians/labels")
    index = RFParams.sharing_index(fit_cfg.sharing, geom.num,
                                   None if labels is None else torch.as_tensor(np.asarray(labels)))
    init = {"opacity": fit_cfg.init_opacity, "roughness": fit_cfg.init_roughness, "gamma_abs": fit_cfg.init_gamma_abs,
            "gamma_phase_rad": fit_cfg.init_gamma_phase_rad}
    torch.manual_seed(seed)
    model = WidebandModel(index, float(freqs.min()), float(freqs.max()), knots=wb.knots, init=init,
                          net=wb.net_kwargs(), seed=seed)
    res = fit_wideband(model, pairs, freqs, target, wb, lr=fit_cfg.lr, s_tx_lr=fit_cfg.s_tx_lr, learn=fit_cfg.learn,
                       seed=seed, progress=progress)

    prov = Provenance(stage="rf-fit", config_toml=config_toml, device="cpu")
    prov.add_input(scene_path)
    prov.add_input(measurements_path)
    timings = {"trace": trace_s, "base_fit": res.base_time_s, "net_fit": res.net_time_s}
    extra_attrs = {f"render.{k}": getattr(render_cfg, k) for k in RENDER_KEYS + ("visibility_opacity",)}
    extra_attrs.update(ant.describe())
    common = dict(split=str(config.get("split", "data")), scene=scene, meas=meas, task=task, freqs=freqs, rows=rows,
                  wb=wb, fit_cfg=fit_cfg, res=res, extra_attrs=extra_attrs, trace_s=trace_s, seed=seed,
                  num_pairs=int(pairs.link.numel()))
    if wb.save_base:
        base = WidebandModel(index, float(freqs.min()), float(freqs.max()), knots=wb.knots, init=init,
                             net=wb.net_kwargs(), seed=seed)
        base.load_state_dict({k: torch.as_tensor(v) for k, v in res.base_state.items()})
        prov.wall_time_s = time.time() - t_start
        prov.extra = {"seed": seed, "step": "base only (network off)", **timings}
        _write(out_path.with_name(out_path.stem + "_base" + out_path.suffix), base, network=False, prov=prov,
               **common)
    prov.wall_time_s = time.time() - t_start
    prov.extra = {"seed": seed, "train_rows": int(len(rows)), **timings}
    _write(out_path, model, network=wb.net_iterations > 0, prov=prov, **common)
    return RfFitResult(path=out_path, num_gaussians=geom.num, num_train_links=int(len(rows)), freqs_hz=freqs.tolist(),
                       train_mae_db=res.train_mae_db, initial_mae_db=res.initial_mae_db,
                       iterations=wb.base_iterations + wb.net_iterations, wall_time_s=time.time() - t_start,
                       trace_time_s=trace_s, occlusion=getattr(provider, "name", "off"), timings_s=timings)


def _write(out_path, model: WidebandModel, *, network: bool, scene, meas, task, freqs, rows, wb, fit_cfg, res,
           extra_attrs, trace_s, seed, num_pairs, prov, split) -> None:
    model.use_network = False
    with torch.no_grad():
        opacity, rough, g_abs, g_ang = model.attributes(torch.as_tensor(freqs[:1]))
        s_tx = model.s_tx(torch.as_tensor(freqs)).numpy()
    g_ang = torch.atan2(torch.sin(g_ang), torch.cos(g_ang))
    data = {k: v for k, v in scene.data.items() if k.startswith("gaussians/")}
    data.update({"rf/opacity": opacity.numpy().copy(), "rf/roughness": rough[:, 0].numpy().copy(),
                 "rf/gamma_abs": g_abs[:, 0].numpy().copy(), "rf/gamma_phase_rad": g_ang[:, 0].numpy().copy(),
                 "rf/freq_hz": np.asarray(freqs, dtype=np.float64)})
    model_attrs = {"wideband": 1, "wideband.network": int(network), "wideband.f_min_hz": float(freqs.min()),
                   "wideband.f_max_hz": float(freqs.max()),
                   "renderer": "rfir_stages.rf_fit.wideband (docs/physics.md sections 4, 5 and 7)",
                   "s_tx_db_doc": "s_tx(f) at rf/freq_hz [dB]; wideband.s_tx.knots_db interpolates it over the band"}
    model_attrs.update({f"wideband.{k}": getattr(wb, k) for k in WB_KEYS})
    model_attrs.update(extra_attrs)
    model_group = {"s_tx_db": s_tx, "@attrs": model_attrs}
    model_group.update({STATE_PREFIX + k: v for k, v in model.flat_state().items()})
    mae = res.train_mae_db if network else res.base_train_mae_db
    training_attrs = {"loss": "db_mse", "base_iterations": wb.base_iterations,
                      "net_iterations": wb.net_iterations if network else 0, "lr": fit_cfg.lr, "net_lr": wb.net_lr,
                      "freqs_per_step": wb.freqs_per_step, "sharing": fit_cfg.sharing, "learn": ",".join(fit_cfg.learn),
                      "seed": seed, "train_mae_db": mae, "base_train_mae_db": res.base_train_mae_db,
                      "initial_mae_db": res.initial_mae_db, "base_time_s": res.base_time_s,
                      "net_time_s": res.net_time_s if network else 0.0, "trace_time_s": trace_s,
                      "num_pairs": num_pairs, "measurements": str(meas.path),
                      "split": str(split), "split_protocol": f"training rows of the split protocol {split!r}"}
    training = {"loss_curve": res.base_curve, "train_rows": np.asarray(rows, dtype=np.int64), "@attrs": training_attrs}
    if network and res.net_curve.size:
        training["net_loss_curve"] = res.net_curve
    attrs = {"task": task, "scene": str(meas.attrs.get("scene", scene.attrs.get("scene", "")))}
    if "label_names" in scene.attrs:
        attrs["label_names"] = np.asarray([str(s) for s in scene.attrs["label_names"]], dtype=object)
    write_artifact(out_path, "rf", data, attrs=attrs, provenance=prov,
                   free={"model": model_group, "training": training})
