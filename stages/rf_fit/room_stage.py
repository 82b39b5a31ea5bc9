"""rf-fit of RSSI links with the physical room model (rfir_stages.model.room, docs/physics.md section 8.10).

Called by rssi_fit.run_rssi for every RSSI fit. Materials are fitted per label
class (desk_03 -> desk) when the scene has labels, else per segment (k-means of the Gaussians on
position and normal); `[rf_fit.room] sharing` overrides. The fit itself is fit_physical.fit_materials
(the starts, start switching and best-state rules of the RCS model). The artifact holds the Gaussians,
the materials (model.artifact.physical_fields) and the room settings, so predict rssi can trace any
new link.
"""
from __future__ import annotations

import time
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import torch

from rfir_core.artifacts import write_artifact
from rfir_core.text import plural, standard_errors
from rfir_core.errors import ConfigError
from rfir_core.physics.materials import ITU_MATERIALS, power_law
from rfir_core.provenance import Provenance
from rfir_stages.model.antenna_patterns import LinkAxes
from rfir_stages.model.artifact import physical_fields
from rfir_stages.model.device_gains import CHOICES as DEVICE_CHOICES
from rfir_stages.model.device_gains import DeviceGains, device_index, whole_device_rows
from rfir_stages.model.fit_physical import (MODEL_ERROR_DB, STARTS, PhysicalFitConfig, fit_materials,
                                             gains_from_all_links, link_weights, material_index, reflection_ranges,
                                             training_predictor)
from rfir_stages.model.material_checks import check_materials
from rfir_stages.model.physical import PairSettings
from rfir_stages.model.residual import SE_MARGIN
from rfir_stages.model.room import (BANDS, BLE_CHANNELS_HZ, SCATTERING_CHOICES, RoomGeometry, RoomLinks, RoomSettings,
                                   band_of)
from rfir_stages.model.room_paths import PATCH_EXTENTS, extent_grids
from rfir_stages.predict.rssi import rssi_defaults
from rfir_stages.predict.rssi_checks import floor_grid
from rfir_stages.model.tabulated import DEFAULT_THICKNESS_M, TYPICAL_THICKNESS_M, named_material, take_tabulated

from . import radio_inset_stage as radio_insets
from .device_choice import MARGIN_DB, MIN_VALIDATION_LINKS, choose_device_gains, held_out_rows
from .physical_stage import attach_ranges, bound_warnings, range_words
from .residual_choice import choose_residual_terms, clutter_map, parse_request, training_residuals
from .result import RfFitResult

MODEL_KIND = "rssi_physical"
SHARINGS = ("auto", "class", "label", "segment", "global")
FIT_KEYS = ("iterations", "start_iterations", "lr", "fit_gain", "half_space", "sigma_exponent")


def simulated_depth(meas) -> int | None:
    """The interactions per path the measurements were simulated to (the simulator's physics.max_depth,
    recorded in the file's simulator attributes), or None for data that record none (measured data)."""
    free = getattr(meas, "free", None) or {}
    depth = (free.get("simulator@attrs") or {}).get("physics.max_depth")
    return None if depth is None else int(depth)


def simulated_channels(meas) -> tuple[float, ...]:
    """The channels [Hz] whose powers the simulator averaged per link (its `channels_hz` attribute; rfir simulate's
    simulate.rssi.channels_hz), () for one frequency or data that record none."""
    text = str(((getattr(meas, "free", None) or {}).get("simulator@attrs") or {}).get("channels_hz", "")).strip()
    return tuple(float(v) for v in text.split(",")) if text else ()


def ideal_devices(meas) -> bool:
    """True for rfir simulate's own data (the file records its simulator, and no measured-like transform
    added device gains, patterns and fading to them): every device is ideal, with no gain of its own."""
    attrs = (getattr(meas, "free", None) or {}).get("simulator@attrs")
    return attrs is not None and "measured_like" not in attrs


def room_config(config: dict, depth: int | None = None, ideal: bool = True
                ) -> tuple[RoomSettings, PhysicalFitConfig, str]:
    """(room settings, fit settings, sharing) from the [rf_fit] table ([rf_fit.room] and [rf_fit.physical]).

    max_interactions = "auto" (the default): `depth`, the interactions per path the measurements were
    simulated to (simulated_depth), where they record one (max_order is lowered to it if above), else
    room_paths.MAX_INTERACTIONS; interactions_words says which. device_gains = "auto" (the default): "off"
    for data from ideal devices (`ideal`, from ideal_devices), else "validate" (measured data: run_room
    chooses by validation on held-out positions, device_choice.py); device_words says which."""
    table = dict(config.get("room", {}) or {})
    if table.get("device_gains", "auto") == "auto":
        table["device_gains"] = "off" if ideal else "validate"
    interactions = table.pop("max_interactions", "auto")
    if interactions == "auto":
        if depth is not None:
            table["max_interactions"] = depth
            table["max_order"] = min(int(table.get("max_order", RoomSettings.max_order)), depth)
    elif isinstance(interactions, bool) or not isinstance(interactions, int):
        raise ConfigError(f"rf_fit.room.max_interactions = {interactions!r}: expected \"auto\" or a whole number")
    else:
        table["max_interactions"] = interactions
    sharing = str(table.pop("sharing", "auto"))
    try:   # run_room's residual terms, checked before any work
        parse_request(table.get("residual_terms", "auto"))
    except ValueError as e:
        raise ConfigError(f"rf_fit.room.residual_terms: {e}") from None
    if sharing not in SHARINGS:
        raise ConfigError(f"rf_fit.room.sharing = {sharing!r}: expected one of {', '.join(SHARINGS)}")
    known = {f.name for f in fields(RoomSettings)}
    unknown = sorted(set(table) - known)
    if unknown:
        raise ConfigError(f"rf_fit.room: unknown key(s) {', '.join(unknown)} (known: {', '.join(sorted(known))})")
    settings = RoomSettings(**{k: type(getattr(RoomSettings, k))(v) for k, v in table.items()})
    if settings.polarisation not in ("V", "H") or settings.max_order < 0:
        raise ConfigError("rf_fit.room: polarisation must be 'V' or 'H' and max_order >= 0")
    if settings.max_interactions < settings.max_order:
        raise ConfigError(f"rf_fit.room.max_interactions = {settings.max_interactions} is below max_order = "
                          f"{settings.max_order}: paths of {settings.max_order} reflections would all be dropped")
    if settings.small_patch_share < 0 or settings.merge_scatter_factor < 0 or settings.third_order_small_reflections < 0:
        raise ConfigError("rf_fit.room: small_patch_share, merge_scatter_factor and third_order_small_reflections "
                          "must be >= 0")
    if settings.band not in BANDS:
        raise ConfigError(f"rf_fit.room.band = {settings.band!r}: expected one of {', '.join(BANDS)}")
    if settings.radio_insets not in radio_insets.CHOICES:
        raise ConfigError(f"rf_fit.room.radio_insets = {settings.radio_insets!r}: expected one of "
                          f"{', '.join(radio_insets.CHOICES)}")
    if settings.starts_kept < 1:
        raise ConfigError(f"rf_fit.room.starts_kept = {settings.starts_kept}: expected at least 1")
    if settings.scattering not in SCATTERING_CHOICES:
        raise ConfigError(f"rf_fit.room.scattering = {settings.scattering!r}: expected one of "
                          f"{', '.join(SCATTERING_CHOICES)}")
    if settings.patch_extent not in PATCH_EXTENTS:
        raise ConfigError(f"rf_fit.room.patch_extent = {settings.patch_extent!r}: expected one of "
                          f"{', '.join(PATCH_EXTENTS)}")
    if settings.device_gains not in DEVICE_CHOICES + ("validate",) or not settings.device_gain_prior_db > 0:
        raise ConfigError(f"rf_fit.room: device_gains must be \"auto\" or one of {', '.join(DEVICE_CHOICES)} and "
                          "device_gain_prior_db > 0")
    phys = dict(config.get("physical", {}) or {})
    fit_cfg = PhysicalFitConfig(**{k: phys[k] for k in FIT_KEYS if k in phys}, starts_kept=settings.starts_kept,
                                shared_scattering=settings.scattering == "shared")
    return settings, fit_cfg, sharing


def interactions_words(config: dict, depth: int | None) -> str:
    """Where rf-fit's interactions per path come from, as it prints it after the number."""
    if (config.get("room", {}) or {}).get("max_interactions", "auto") != "auto":
        return "rf_fit.room.max_interactions"
    if depth is None:
        return "auto: the measurements record no simulator depth"
    return "auto: the depth the measurements were simulated to, physics.max_depth"


def device_words(config: dict, ideal: bool) -> str:
    """Where rf-fit's device gains come from, as it prints it after them."""
    if (config.get("room", {}) or {}).get("device_gains", "auto") != "auto":
        return "rf_fit.room.device_gains"
    return ("auto: simulated with ideal devices" if ideal else
            "auto: measured data, or simulated data given device gains: chosen by validation on held-out positions")


def _higher_orders(settings: RoomSettings) -> str:
    """Which patches the reflections above the first use, as rf-fit prints it."""
    if settings.max_order < 1:
        return "none"
    if settings.max_order < 2:
        return "every patch"
    out = f"order 2 off patches of at least {settings.higher_order_min_area_m2:g} m^2"
    if settings.max_order >= 3:
        out += f", order{' 3' if settings.max_order == 3 else 's 3 and up'} off patches of at least " \
               f"{settings.third_order_min_area_m2:g} m^2"
        if settings.third_order_small_reflections > 0:
            out += f" ({settings.third_order_small_reflections} of them may be off patches of at least " \
                   f"{settings.higher_order_min_area_m2:g} m^2)"
    return out


def patch_grouping(settings: RoomSettings, merge_tol_m: float) -> str:
    """How the Gaussians were grouped into planar patches, as rf-fit prints it (merge_tol_m: PatchSet's)."""
    if merge_tol_m > 0:
        return (f"planes fitted to an RMS offset of at most {merge_tol_m * 100:.2g} cm, "
                f"{settings.merge_scatter_factor:g} x the Gaussians' scatter of "
                f"{merge_tol_m / settings.merge_scatter_factor * 100:.2g} cm about their planes")
    return f"neighbours within {settings.coplanar_m:g} m of one plane joined"


def diffuse_words(settings: RoomSettings, num_cells: int) -> str:
    """The diffuse term's cells, as rf-fit prints it."""
    if not settings.diffuse:
        return "off"
    pooled = settings.small_patch_share * settings.diffuse_cell_m ** 2
    pooling = (f"patches under {pooled:.2g} m^2 pooled by material, facing and voxel" if pooled > 0
               else "a cell per patch and voxel")
    return f"on ({num_cells} cells of about {settings.diffuse_cell_m:g} m, {pooling}; through the slabs it crosses)"


def room_materials(sharing: str, scene, geom) -> tuple[np.ndarray, list[str], str]:
    """(material of each Gaussian [G], material names, the sharing used)."""
    labels = scene.get("gaussians/labels")
    names = [str(s) for s in scene.attrs.get("label_names", [])] if "label_names" in scene.attrs else None
    if sharing == "auto":
        sharing = "class" if labels is not None else "segment"
    if sharing == "class" and labels is None:
        raise ConfigError("rf_fit.room.sharing = 'class' needs gaussians/labels in the scene; use 'segment'")
    idx, mnames = material_index(sharing, geom.num, None if labels is None else torch.as_tensor(labels),
                                 geom.means, geom.normals, label_names=names)
    return idx.numpy(), mnames, sharing


def name_priors(names: list[str]) -> dict:
    """{material index: (eps_r, sigma at 1 GHz [S/m], thickness [m])} for materials whose name contains an
    ITU-R P.2040 material ("glass_partition" -> glass), the law's values at 1 GHz and a typical thickness."""

    out = {}
    for i, name in enumerate(names):
        key = named_material(name)
        if key is not None:
            a, _, c, _, _, _ = ITU_MATERIALS[key]
            out[i] = (a, max(c, 1e-4), TYPICAL_THICKNESS_M.get(key, DEFAULT_THICKNESS_M))
    return out


def fit_room_materials(links, room: RoomGeometry, settings: RoomSettings, num_materials: int, target_db: np.ndarray,
                       fit_cfg: PhysicalFitConfig, progress, priors: dict, devices, weights: np.ndarray | None = None):
    """fit_physical.fit_materials on the traced links; where the third order reflects off desk-sized patches
    (third_order_small_reflections), first without those paths, then with them from there: from the starts alone
    the full fit can end in a poorer optimum than the simpler fit's materials, and started from those it keeps
    the better of the two."""
    kept = min(fit_cfg.starts_kept, len(STARTS))
    if kept > 1:
        progress.log(f"the {kept} best starting materials after {fit_cfg.start_iterations} steps are "
                     "each fitted to the end, the lowest final training loss kept, then each material tried with "
                     "the others' fitted values (rf_fit.room.starts_kept)")
    extra = links.paths.small_third_order(room.patches.area, settings.third_order_min_area_m2)
    if settings.third_order_small_reflections <= 0 or not bool(extra.any()):
        res = fit_materials(links, num_materials, target_db, fit_cfg, progress, label="physical room",
                            priors=priors, devices=devices, weights=weights)
        _log_crossing(res, progress)
        return res
    progress.log(f"fitting first without the {int(extra.sum())} third-order paths off patches under "
                 f"{settings.third_order_min_area_m2:g} m^2, then with them from there")
    first = fit_materials(links.select_paths(~extra), num_materials, target_db, fit_cfg, progress,
                          label="physical room, without them", priors=priors, devices=devices, weights=weights)
    _log_crossing(first, progress)
    res = fit_materials(links, num_materials, target_db, fit_cfg, progress, label="physical room, with them",
                        priors=priors, devices=devices, initial=first.params, weights=weights)
    # one fit as rf-fit reports it and stores it: from the first step's start, its loss curve through both steps,
    # in the time of both
    res.extra = {**first.extra, "continued_from_mae_db": res.initial_mae_db}
    res.loss_curve = np.concatenate([first.loss_curve, res.loss_curve])
    res.initial_mae_db, res.wall_time_s = first.initial_mae_db, first.wall_time_s + res.wall_time_s
    res.steps += first.steps
    res.start = first.start
    return res


def _take_tabulated(links, res, target_db: np.ndarray, check, freq_hz: float, names: list[str], devices,
                    tabulated: list[str], progress) -> None:
    """tabulated.take_tabulated on the fit `res` (its params replaced in place, its training MAE on the fit links
    `links` / target_db updated), decided on `check` = (links, target_db [M, 1]) of training links the fit did not
    use (None: on the fit links); the key taken written into tabulated [N] per material, and printed."""

    pred = training_predictor(links, torch.as_tensor(target_db), devices)
    decide, decide_db = (pred, target_db) if check is None else (
        training_predictor(check[0], torch.as_tensor(check[1])), check[1])   # device gains fit every link: no check
    taken = take_tabulated(decide, res.params, decide_db, freq_hz, names, margin=SE_MARGIN)
    for t in taken:
        tabulated[t.index] = t.key
    with torch.no_grad():
        res.train_mae_db = float((pred(res.params) - torch.as_tensor(target_db)).abs().mean())
    on = "the links it was fitted on" if check is None else f"{plural(len(check[1]), 'training link')} the fit did not use"
    if taken:
        progress.log(f"materials the training links cannot tell from a tabulated one (ITU-R P.2040 at "
                     f"{freq_hz / 1e9:g} GHz, within {SE_MARGIN:g} standard error on {on}), taken as it: " + "; ".join(
                         f"{names[t.index]}: {t.key}"
                         + ("" if t.key == "metal" else f" {t.thickness_m * 100:.1f} cm")
                         + f" ({standard_errors(t.increase_se)})" for t in taken)
                     + f"; training MAE {res.train_mae_db:.3f} dB")
    else:
        progress.log(f"no fitted material is within one standard error of a tabulated one (ITU-R P.2040) on {on}: "
                     "all kept as fitted")


# links each device's gain keeps at least where the fit takes rf_fit.room.fit_links of the training links with device
# gains on (fewer: every training link is fitted): a gain's standard error is then the residuals' spread / sqrt(30),
# 0.5 dB for the 2.5-3 dB of measured surveys, well inside the gains' 3 dB prior
MIN_DEVICE_LINKS = 30


def devices_kept(which: str, rows: np.ndarray, tx: np.ndarray, rx: np.ndarray, ids: dict) -> bool:
    """True when every device of the side(s) `which` ("tx", "rx", "both") gets a gain fitted to (device_gains.
    device_index over the training links tx, rx [M, 3] m, ids {side: [M] or None}) has at least MIN_DEVICE_LINKS links
    among rows [R]: a gain per fixed anchor keeps hundreds in a subsample, one per surveyed position a few."""
    for side, pts in (("tx", tx), ("rx", rx)):
        if which in (side, "both"):
            _, device, _ = device_index(pts, ids[side])
            if np.bincount(device[rows], minlength=int(device.max()) + 1).min() < MIN_DEVICE_LINKS:
                return False
    return True


def _whole_devices_words(settings: RoomSettings, fit: np.ndarray, tx: np.ndarray, rx: np.ndarray, ids: dict) -> str:
    """What the fit takes where an evenly spaced subsample would leave a device under MIN_DEVICE_LINKS links."""
    count = {s: len(np.unique(device_index(p, ids[s])[1][fit])) for s, p in (("tx", tx), ("rx", rx))}
    return (f"device gains on: the materials fitted on {len(fit)} of the {len(tx)} training links, whole devices "
            f"({count['tx']} tx and {count['rx']} rx devices with all their links; rf_fit.room.fit_links = "
            f"{settings.fit_links}: evenly spaced links would leave a device under {MIN_DEVICE_LINKS}), the device "
            "gains profiled out in closed form at each step, then every device's gain from all its links")


def check_rows(num_links: int, fit: np.ndarray) -> np.ndarray:
    """Rows [C] of up to len(fit) of the num_links training links that are not in fit, evenly spaced."""
    rest = np.setdiff1d(np.arange(num_links), fit)
    if len(rest) == 0:
        return rest
    return rest[np.unique(np.linspace(0, len(rest) - 1, min(len(fit), len(rest))).round().astype(np.int64))]


def _check_links(room, tx, rx, fit: np.ndarray, target_db: np.ndarray, freq_hz: float, band: str = "coherent",
                 axes: LinkAxes = LinkAxes()):
    """(links, target_db [M, 1]) of up to len(fit) training links the fit did not use, evenly spaced, or None when
    it used them all: the tabulated step decides on them, since every alternative to the fitted values looks
    worse on the links those values were fitted to (rfir_stages.model.tabulated). axes: the LinkAxes of tx, rx."""
    rest = check_rows(len(tx), fit)
    if len(rest) == 0:
        return None
    if band == "coherent":
        return room.links(tx[rest], rx[rest], np.full(len(rest), freq_hz), axes=axes.rows(rest)), target_db[rest, None]
    return room.band_links(tx[rest], rx[rest], freq_hz, band, axes=axes.rows(rest)), target_db[rest, None]


def _check_materials(links, res, target_db: np.ndarray, fit: np.ndarray, check, names: list[str], freq_hz: float,
                     devices):
    """(material_checks.check_materials flags of the fit `res`, the links they were scored on in words): on
    `check` = (links, target_db [M, 1]) of training links the fit did not use (_check_links; None with device
    gains, which fit every link), else on the fitted links `links` (target_db[fit]; where the fitted values have
    the fit's optimism, and no alternative is taken). An alternative taken is put into res.params."""
    if check is None:
        pred, tgt = training_predictor(links, torch.as_tensor(target_db[fit, None]), devices), target_db[fit, None]
        on = "the fitted links"
    else:
        pred, tgt = training_predictor(check[0], torch.as_tensor(check[1])), check[1]
        on = f"{plural(len(tgt), 'training link')} the fit did not use"
    with torch.no_grad():
        rows = material_rows(res.params.values(), names, freq_hz)
    flags = check_materials(pred, res.params, tgt, rows, freq_hz, held_out=check is not None)
    if any(f.taken for f in flags):
        with torch.no_grad():
            fitted = training_predictor(links, torch.as_tensor(target_db[fit, None]), devices)(res.params)
            res.train_mae_db = float((fitted - torch.as_tensor(target_db[fit, None])).abs().mean())
    return flags, on


def _log_crossing(res, progress) -> None:
    """Which materials the fit took from another start's fit (fit_physical._cross_finals), with the loss."""
    n = res.extra.get("crossed_materials", 0)
    if n:
        progress.log(f"{n} material(s) took another start's fitted values: training loss "
                     f"{min(res.extra['final_losses'].values()):.4g} -> {res.extra['crossed_loss']:.4g} (after fitting on)")


class ValidationFits:
    """The fits the "auto" choices score on held-out positions: the materials fitted without device gains (one
    start carried through, the system gain fitted) on given rows of given links, each fitted once. The band
    and the device-gain choice hold out the same positions (device_choice.held_out_rows with the same seed), so
    where the band stays coherent the device choice reuses the band's fit."""

    def __init__(self, room, settings: RoomSettings, names: list[str], target_db: np.ndarray,
                 fit_cfg: PhysicalFitConfig, priors: dict, progress):
        self.room, self.settings, self.names, self.target_db = room, settings, names, target_db
        self.quick, self.priors, self.progress = replace(fit_cfg, fit_gain=True, starts_kept=1), priors, progress
        self._done: dict = {}

    def params(self, links, rows: np.ndarray, message: str):
        """MaterialParams fitted on links.select_links(rows) to target_db[rows]; message: printed when it fits."""
        key = (id(links), np.asarray(rows).tobytes())
        if key not in self._done:
            self.progress.log(message)
            self._done[key] = fit_room_materials(links.select_links(torch.as_tensor(rows)), self.room, self.settings,
                                                 len(self.names), self.target_db[rows, None], self.quick,
                                                 self.progress, self.priors, None).params
        return self._done[key]

    def predict(self, links, rows: np.ndarray, message: str) -> np.ndarray:
        """Path gain [M] dB of every link of `links` with the materials fitted on `rows`."""
        params = self.params(links, rows, message)
        with torch.no_grad():
            return training_predictor(links, torch.as_tensor(self.target_db[:, None]))(params)[:, 0].numpy()


def _choose_band(links, room, tx, rx, freq_hz: float, target_db: np.ndarray, fits: ValidationFits, seed: int):
    """(band, its links, reason) for rf_fit.room.band = "auto" on measured data: the coherent links `links` of
    tx, rx [M, 3] m (target_db [M] dB) are split as device_choice splits them (the links at HELD_SHARE of the
    roaming side's positions held out); the materials are fitted once, coherently and without device gains, on
    the others (fits); each sum (coherent, ble, incoherent) then predicts every link with those materials, its
    system gain refitted (the median training residual, the MAE's optimum), and is scored on the held-out links.
    A sum other than coherent wins where it lowers the held-out MAE by MARGIN_DB."""
    held, side = held_out_rows(tx, rx, seed)
    if held.sum() < MIN_VALIDATION_LINKS or (~held).sum() < MIN_VALIDATION_LINKS:
        return "coherent", links, (f"auto: too few links ({len(held)}) to validate the band on held-out positions; "
                                   "rf_fit.room.band sets it")
    train = np.flatnonzero(~held)
    params = fits.params(links, train, f"band: fitting coherently on {len(train)} of {len(tx)} links to validate the sums")
    candidates = {"coherent": links,
                  "ble": band_of(links, "ble", freq_hz),
                  "incoherent": RoomLinks(links.paths, links.diffuse, links.material_of_patch, links.num_materials,
                                          incoherent=True)}
    scores = {}
    with torch.no_grad():
        for band, lk in candidates.items():
            pred = training_predictor(lk, torch.as_tensor(target_db[:, None]))(params)[:, 0].numpy()
            residual = target_db - pred
            residual -= np.median(residual[train])
            scores[band] = float(np.abs(residual[held]).mean())
    best = min(scores, key=scores.get)
    if scores[best] > scores["coherent"] - MARGIN_DB:
        best = "coherent"
    shown = ", ".join(f"{k} {v:.2f}" for k, v in scores.items())
    reason = (f"auto: measured data: validated on {int(held.sum())} training links at the {side} positions held out "
              f"of a coherent fit, its materials held fixed and the system gain refitted for each sum (MAE dB: "
              f"{shown}); rf_fit.room.band sets it")
    return best, candidates[best], reason


def run_room(scene, meas, geom, rows, held, tx, rx, freq_hz: float, target_db: np.ndarray, scene_path,
             measurements_path, out_path, config: dict, render_cfg, cfg: dict, *, seed: int, config_toml: str,
             progress, t_start: float, antennas=None, axes=None):
    """Trace, fit and write; returns stage.RfFitResult. antennas: antenna_patterns.RoomAntennas (None: isotropic);
    axes: antenna_patterns.LinkAxes of the training links tx, rx (None: each end's own axis)."""
    axes = axes or LinkAxes()

    depth, ideal = simulated_depth(meas), ideal_devices(meas)
    settings, fit_cfg, sharing = room_config(config, depth, ideal)
    if settings.device_gains != "off" and not fit_cfg.fit_gain:
        # the gains' prior is zero-mean: without a system gain the common level of the data would go into
        # the gains of the devices the fit saw, and an unseen device would miss it
        fit_cfg.fit_gain = True
        progress.log("device gains on: the system gain is fitted too (the gains are offsets about it)")
    material, names, sharing = room_materials(sharing, scene, geom)
    labels = scene.get("gaussians/labels")
    t0 = time.time()

    def make_room(g, lab, mat) -> RoomGeometry:
        """The room of Gaussians g, labels lab [G] (None: none) and materials mat [G] under these settings."""
        return RoomGeometry(g, None if lab is None else torch.as_tensor(np.asarray(lab, dtype=np.int64)), mat, settings,
                            render_cfg.alpha_min, str(config.get("occlusion", "auto")), antennas=antennas)

    room = make_room(geom, labels, material)
    progress.log(f"rf-fit (rssi, physical room model): {geom.num} Gaussians in {room.patches.num} planar patches "
                 f"({patch_grouping(settings, room.patches.merge_tol_m)}), "
                 f"{plural(len(rows), 'training link')}, materials per {sharing} ({len(names)}; scattering S "
                 f"{'one for all' if settings.scattering == 'shared' else 'one per material'}), patch extents "
                 f"{settings.patch_extent}, reflections up to order "
                 f"{settings.max_order} ({_higher_orders(settings)}), at most {settings.max_interactions} "
                 f"interactions per path (reflections and surfaces crossed; {interactions_words(config, depth)}), "
                 f"diffuse {diffuse_words(settings, room.cells.area.size)}, polarisation "
                 f"{settings.polarisation}, {room.antennas.words()}, system gain "
                 f"{'fitted' if fit_cfg.fit_gain else '0 dB'}, device gains "
                 + ("off" if settings.device_gains == "off" else
                    "chosen by validation" if settings.device_gains == "validate" else
                    f"per {settings.device_gains} (prior {settings.device_gain_prior_db:g} dB)")
                 + f" ({device_words(config, ideal)})")
    ids = {side: (None if meas.get(f"{side}_id") is None else np.asarray(meas[f"{side}_id"])[rows])
           for side in ("tx", "rx")}
    fit = np.arange(len(tx))
    sub = np.linspace(0, len(tx) - 1, settings.fit_links).round().astype(np.int64) \
        if 0 < settings.fit_links < len(tx) else fit
    if settings.device_gains not in ("off", "validate") and len(sub) < len(tx) and \
            not devices_kept(settings.device_gains, sub, tx, rx, ids):
        # a gain per surveyed position has a few links: the subsample takes whole devices (whole_device_rows)
        fit = whole_device_rows(settings.device_gains, settings.fit_links, tx, rx, ids)
        progress.log(_whole_devices_words(settings, fit, tx, rx, ids))
    elif len(sub) < len(tx):
        fit = sub
        progress.log(f"fitting on {len(fit)} of the {len(tx)} training links, evenly spaced "
                     f"(rf_fit.room.fit_links = {settings.fit_links}"
                     + (f"; every device keeps at least {MIN_DEVICE_LINKS} links)"
                        if settings.device_gains not in ("off", "validate") else ")"))
    band, band_reason = settings.band, "rf_fit.room.band"
    channels = simulated_channels(meas)
    if band == "auto" and ideal and not channels:
        # rfir simulate's data are coherent sums at one frequency unless it averaged channels
        band, band_reason = "coherent", "auto: simulated at one frequency"
    elif band == "auto" and ideal and np.allclose(channels, BLE_CHANNELS_HZ, rtol=0, atol=1e3):
        band, band_reason = "ble", "auto: simulated as the mean over BLE's three advertising channels"
    links = room.band_links(tx[fit], rx[fit], freq_hz, "coherent" if band == "auto" else band, axes=axes.rows(fit))
    trace_s = time.time() - t0
    progress.log(f"traced {links.paths.num} specular paths ({links.paths.num / max(len(fit), 1):.1f} per link) "
                 f"in {trace_s:.1f} s")
    priors = name_priors(names)
    if priors:
        progress.log("starting values from material names (ITU-R P.2040 at 1 GHz): " + "; ".join(
            f"{names[i]}: eps_r {e:g}, sigma {g:g} S/m, {t * 100:g} cm" for i, (e, g, t) in priors.items()))
    fits = ValidationFits(room, settings, names, target_db[fit], fit_cfg, priors, progress)
    if band == "auto":
        band, links, band_reason = _choose_band(links, room, tx[fit], rx[fit], freq_hz, target_db[fit], fits, seed)
    settings = replace(settings, band=band)
    progress.log(f"band: {band} ({band_reason})")
    if settings.device_gains == "validate":
        choice = choose_device_gains(tx[fit], rx[fit], {k: None if v is None else v[fit] for k, v in ids.items()},
                                     target_db[fit], settings.device_gain_prior_db,
                                     lambda rows: fits.predict(links, rows, f"device gains: fitting without them on "
                                                               f"{len(rows)} of {len(fit)} links to validate them"),
                                     seed)
        settings = replace(settings, device_gains=choice.which)
        progress.log(f"device gains: {choice.which} ({choice.reason})")
        if choice.which != "off" and len(fit) < len(tx) and not devices_kept(choice.which, fit, tx, rx, ids):
            fit = whole_device_rows(choice.which, settings.fit_links, tx, rx, ids)
            progress.log(_whole_devices_words(settings, fit, tx, rx, ids))
            links = room.band_links(tx[fit], rx[fit], freq_hz, band, axes=axes.rows(fit))
        elif choice.which != "off" and len(fit) < len(tx):
            progress.log(f"device gains on: every device keeps at least {MIN_DEVICE_LINKS} of the {len(fit)} links "
                         "fitted (rf_fit.room.fit_links)")
    # every training link's devices, the fit's rows among them: a device the fit leaves out gets its gain from all links
    devices = None if settings.device_gains == "off" else DeviceGains(
        settings.device_gains, tx, rx, settings.device_gain_prior_db, ids["tx"], ids["rx"], rows=fit)
    if devices is not None and devices.num_devices > len(tx) / 5:   # under 5 links a gain: they fit the noise
        progress.log(f"warning: {plural(devices.num_devices, 'device gain')} for {plural(len(tx), 'training link')}: "
                     "a gain per device "
                     "fits the links it has and carries to no other position (rf_fit.room.device_gains = auto "
                     "chooses by validation)")
    count, spread = meas.get("sample_count"), meas.get("sample_std_db")
    weights = link_weights(None if count is None else np.asarray(count)[rows][fit],
                           None if spread is None else np.asarray(spread)[rows][fit])
    if weights is not None:
        progress.log(f"links weighted by their sample count and spread (1 / ({MODEL_ERROR_DB:g}^2 + std^2 / n) dB^-2; "
                     f"weights {weights.min():.2f} .. {weights.max():.2f} about a mean of 1)")
    res = fit_room_materials(links, room, settings, len(names), target_db[fit, None], fit_cfg, progress, priors,
                             devices, weights)
    if devices is not None and len(fit) < len(tx) and not devices_kept(settings.device_gains, fit, tx, rx, ids):
        # whole devices fitted (a gain per position): the devices left out get their gains from all their links
        t_gains = time.time()
        gains_from_all_links(devices, res.params, links, fit,
                             lambda r: room.band_links(tx[r], rx[r], freq_hz, band, axes=axes.rows(r)),
                             target_db, link_weights(None if count is None else np.asarray(count)[rows],
                                                     None if spread is None else np.asarray(spread)[rows]))
        progress.log(f"device gains: each from all its links ({len(tx)} training links, {len(tx) - len(fit)} of "
                     f"them traced for it) with the fitted materials in {time.time() - t_gains:.1f} s")
    if devices is not None:
        with torch.no_grad():
            res.params.gain_db += devices.centre()
    tabulated = [""] * len(names)
    # with device gains, decided on the links they were fitted to (the others have no gain fitted for them)
    check = None if devices is not None else _check_links(room, tx, rx, fit, target_db, freq_hz, band, axes)
    if settings.tabulated_materials:
        t_tab = time.time()
        _take_tabulated(links, res, target_db[fit, None], check, freq_hz, names, devices, tabulated, progress)
        progress.log(f"tabulated materials tried in {time.time() - t_tab:.1f} s (rf_fit.room.tabulated_materials)")
    gaussian_data = {k: v for k, v in scene.data.items() if k.startswith("gaussians/")}
    label_names = [str(s) for s in scene.attrs["label_names"]] if "label_names" in scene.attrs else None
    # every training link's residual on this fit: where they gather the radio insets are sought, and the residual terms
    # are fitted to them unless the fit changes below
    residuals, radio_lines = None, []
    searched = settings.radio_insets == "auto" and devices is None and labels is not None and check is not None
    scene_labels = np.asarray(labels) if labels is not None else None
    for _ in range(radio_insets.ROUNDS if searched else 0):
        t_res = time.time()
        residuals = training_residuals(links, room, res.params, devices, tx, rx, fit, target_db, freq_hz, band, axes=axes)
        progress.log(f"residuals of all {plural(len(tx), 'training link')} (the radio insets' search and the residual "
                     f"terms): {time.time() - t_res:.1f} s")
        found = radio_insets.search(
            scene_labels=scene_labels, label_names=label_names, geom=geom, room=room, material=material,
            names=names, links=links, res=res, check=check, tx=tx, rx=rx, fit=fit, check_rows=check_rows(len(tx), fit),
            target_db=target_db, freq_hz=freq_hz, band=band, axes=axes, fit_cfg=fit_cfg, progress=progress,
            residual_db=residuals,
            weights=weights, make_room=make_room)
        if found is None:
            break
        geom, room, links, check, res = found.geom, found.room, found.links, found.check, found.res
        material, names, label_names, scene_labels = found.material, found.names, found.label_names, found.labels
        gaussian_data.update({"gaussians/labels": found.labels, "gaussians/means": geom.means.numpy()})
        radio_lines += found.lines
        tabulated = [""] * len(names)
        if settings.tabulated_materials:
            _take_tabulated(links, res, target_db[fit, None], check, freq_hz, names, devices, tabulated, progress)
        residuals = None
    radio_words = "; ".join(radio_lines)
    if devices is not None:
        for side, g in devices.gains.items():
            g = g.detach().numpy()
            progress.log(f"device gains ({side}, {len(g)} devices): mean {g.mean():+.2f} dB, spread {g.std():.2f} dB, "
                         f"range {g.min():+.2f} .. {g.max():+.2f} dB; devices the fit did not see get 0 dB")
    t_check = time.time()
    flags, flags_on = _check_materials(links, res, target_db, fit, check, names, freq_hz, devices)
    progress.log(f"materials implausible for their surface: {len(flags)}, alternatives scored on {flags_on} in "
                 f"{time.time() - t_check:.1f} s")
    for f in flags:
        if f.taken_key:
            tabulated[f.index] = f.taken_key
    seen = np.zeros(len(names), bool)
    seen[room.material_of_patch[np.unique(links.paths.patch[links.paths.kind > 0].numpy())]] = True
    unseen = [n for n, s in zip(names, seen) if not s]
    if unseen:
        progress.log(f"warning: no training path reflects off or crosses {', '.join(unseen)}: "
                     "their materials keep the starting values")
    t_ranges = time.time()
    ranges = (reflection_ranges(links, res.params, target_db[fit, None], freq_hz, devices, progress)
              if settings.reflection_ranges else None)
    ranges_s = time.time() - t_ranges
    # residual terms in dB on the fitted physics, chosen on the training links (residual_choice; physics.md 8.15)
    means, t_terms = geom.means.numpy(), time.time()
    if residuals is None or any(f.taken for f in flags):
        residuals = training_residuals(links, room, res.params, devices, tx, rx, fit, target_db, freq_hz, band, axes=axes)
    terms = choose_residual_terms(tx, rx, ids, residuals,
                                  means.min(0)[:2], means.max(0)[:2], seed,
                                  settings.residual_terms)
    progress.log(f"residual terms: {terms.which} ({terms.reason})"
                 + ("" if terms.terms is None else f": {terms.terms.describe()}") + f"; {time.time() - t_terms:.1f} s")
    with torch.no_grad():
        vals = res.params.values()
    data, model_attrs = physical_fields(vals, torch.as_tensor(material), room.areas, np.asarray([freq_hz]),
                                        PairSettings(opacity=settings.opacity, polarisation=settings.polarisation),
                                        names, float(res.params.gain_db.detach()))
    model_attrs["material_tabulated"] = np.asarray(tabulated, dtype=object)   # "": as fitted
    model_attrs["radio_insets"] = radio_words     # the surfaces rf-fit moved or gave a material of their own
    flag_lines = {f.index: f.words(flags_on) for f in flags}
    model_attrs["material_check"] = np.asarray([flag_lines.get(i, "") for i in range(len(names))], dtype=object)
    model_attrs.update({"model_kind": MODEL_KIND, "sharing": sharing,
                        "model_doc": "room paths (images over planar patches) + diffuse, physical materials "
                                     "(docs/physics.md section 8.10)"})
    model_attrs.update({f"room.{f.name}": getattr(settings, f.name) for f in fields(RoomSettings)})
    model_attrs.update(room.antennas.attrs())     # RoomPredictor weights its paths with them too
    model_attrs["render.alpha_min"] = render_cfg.alpha_min
    model_attrs["geometry_key"] = room.geometry_key()     # the stored surfel areas are these Gaussians'
    data.update(gaussian_data)
    data["rf/freq_hz"] = np.asarray([freq_hz], np.float64)
    if ranges is not None:
        data["material/gamma_normal_range"] = np.asarray(ranges, np.float64)
    t_map = time.time()
    map_rows = map_crossings(room, geom) if settings.map_visibility and settings.diffuse else {}
    if map_rows:
        model_attrs["map_crossings_key"] = room.crossings_key()
        progress.log(f"kept the surfaces crossed from the default map's {len(map_rows['map_rx_m'])} receivers to "
                     f"{map_rows['map_cell_crossings'].shape[1]} diffuse cells in the model "
                     f"({map_rows['map_cell_crossings'].nbytes / 1e6:.1f} MB, {time.time() - t_map:.1f} s; "
                     "rf_fit.room.map_visibility)")
    training_attrs = {"loss": fit_cfg.loss, "iterations": fit_cfg.iterations, "lr": fit_cfg.lr, "seed": seed,
                      "train_mae_db": res.train_mae_db, "initial_mae_db": res.initial_mae_db,
                      "wall_time_s": time.time() - t_start, "fit_time_s": res.wall_time_s, "trace_time_s": trace_s,
                      "ranges_time_s": ranges_s,
                      "measurements": str(meas.path),
                      "split": cfg["split"], "start": res.start,
                      "unseen_materials": "; ".join(unseen),
                      "split_protocol": ("rows with split == 0 (train)" if cfg["split"] == "file" else
                                         f"transmitters {np.asarray(held).tolist()} held out (seed {seed})")}
    attrs = {"task": "rssi", "scene": str(meas.attrs.get("scene", scene.attrs.get("scene", "")))}
    if label_names is not None:
        attrs["label_names"] = np.asarray(label_names, dtype=object)
    prov = Provenance(stage="rf-fit", config_toml=config_toml, device="cpu")
    prov.add_input(scene_path)
    prov.add_input(measurements_path)
    prov.wall_time_s = time.time() - t_start
    prov.extra = {"seed": seed, "train_rows": int(len(rows)), "trace_time_s": trace_s, "fit_time_s": res.wall_time_s}
    # the patches' occupancy grids: loading the model then rasterises nothing (most of a room's load time)
    model_attrs["patch_extents_key"] = room.extents_key()
    grids = {f"patch_{k}": v for k, v in extent_grids(room.patches).items()}
    if terms.terms is not None:
        model_attrs.update(terms.terms.attrs())
    free = {"model": {"@attrs": model_attrs, **({} if devices is None else devices.table()), **map_rows, **grids,
                      **({} if terms.terms is None else terms.terms.table())},
            "training": {"loss_curve": res.loss_curve, "train_rows": np.asarray(rows, np.int64),
                         "fit_rows": np.asarray(rows, np.int64)[fit],
                         "holdout_tx_ids": np.asarray(held, np.int64), "@attrs": training_attrs}}
    write_artifact(out_path, "rf", data, attrs=attrs, provenance=prov, free=free)
    if terms.terms is not None and terms.terms.field_db_per_m is not None:
        png = Path(out_path).with_name(Path(out_path).stem + "_clutter.png")
        clutter_map(terms.terms, means[np.abs(geom.normals.numpy()[:, 2]) < 0.5, :2], png)
        progress.log(f"clutter field map (where the model put what the floor plan lacks): {png}")
    table = material_rows(vals, names, freq_hz)
    attach_ranges(table, ranges)
    bounds = bound_warnings(table)
    for w in bounds:
        progress.log(f"warning: {w}")
    flags_by = {f.index: f for f in flags}
    for i, (row, key) in enumerate(zip(table, tabulated)):
        row["tabulated"] = key
        progress.log(f"  {row['material']:<16} eps_r {row['eps_r']:5.2f}  sigma {row['sigma_s_per_m']:8.3g} S/m  "
                     f"thickness {row['thickness_m'] * 100:5.1f} cm  S {row['scattering']:.2f}  "
                     f"|Gamma(0)| {row['gamma_normal_abs']:.2f}{range_words(row)}"
                     + (f"  ({key})" if key else "")
                     + ("" if i not in flags_by else f"  [fitted {flags_by[i].reason}, implausible for its surface; "
                        + (f"taken as {flags_by[i].taken}" if flags_by[i].taken else "alternatives at the end") + "]"))
    for i, line in flag_lines.items():
        table[i]["check"] = line
    if ranges is not None:
        progress.log(f"materials' |Gamma(0)| ranges the links allow: {ranges_s:.1f} s "
                     "(rf_fit.room.reflection_ranges)")
    return RfFitResult(out_path, geom.num, int(len(rows)), [float(freq_hz)], res.train_mae_db, res.initial_mae_db,
                       res.steps, time.time() - t_start, trace_s, room.provider.name,
                       {"trace": trace_s, "fit": res.wall_time_s}, materials=table,
                       warnings=([f"materials no training path touches: {', '.join(unseen)}"] if unseen else [])
                       + bounds + [f"implausible for its surface: {line}" for line in flag_lines.values()],
                       material_checks=list(flag_lines.values()))


def map_crossings(room: RoomGeometry, geom) -> dict:
    """{"map_rx_m": [U, 3], "map_cell_crossings": [U, C, K] int32}: each receiver of the default radio map of
    `predict rssi` ([predict.rssi] grid over the Gaussians' floor plan) and the surfaces crossed on its legs
    to the diffuse cells (room_diffuse.CellCrossings), which no transmitter changes (RoomPredictor keeps them)."""

    means = geom.means.numpy()
    height, step = rssi_defaults()["grid"]
    rx = floor_grid((means.min(0), means.max(0)), float(height), float(step))
    with torch.no_grad():
        rows, index = room.cell_crossings(rx)
    points = np.empty((len(rows), 3))
    points[index] = rx                     # the point of each distinct row (CellCrossings' own keying)
    return {"map_rx_m": points, "map_cell_crossings": rows}


def material_rows(vals, names: list[str], freq_hz: float) -> list[dict]:
    """One row per material: eps_r, sigma at freq_hz, thickness, S, |Gamma| at normal incidence."""
    f = torch.tensor([float(freq_hz)], dtype=torch.float64)
    r = vals.normal_reflection(f).abs()[:, 0]
    sigma = power_law(vals.sigma_1ghz, vals.sigma_exponent, f)
    th = vals.thickness_m
    return [{"material": n, "eps_r": float(vals.eps_r[i]), "sigma_s_per_m": float(sigma[i]),
             "thickness_m": 0.0 if th is None else float(th[i]), "scattering": float(vals.scattering[i]),
             "gamma_normal_abs": float(r[i])} for i, n in enumerate(names)]
