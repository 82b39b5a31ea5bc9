"""rf-fit with the physical model (rfir_stages.model): candidates, validation fits, the artifact.

The geometry of every (training link, lit surfel) pair is traced once (`PhysicalSetup`); each
material sharing ("label", "class", "segment", "global") sums it into its aggregated form once, and fits on
any subset of the training links then cost links x materials x angle nodes per step. The residual
(rfir_stages.model.residual) is fitted on top of the final materials (`PhysicalSetup.fit_residual`).
"""
from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from rfir_core.errors import ConfigError
from rfir_stages.model.artifact import physical_fields
from rfir_stages.model.fit_physical import PhysicalFitConfig, PhysicalFitResult, fit_materials, material_index
from rfir_stages.model.identifiability import range_note
from rfir_core.physics.materials import power_law
from rfir_core.physics.polarisation import POLARISATIONS
from rfir_stages.model.physical import EPS_R_MAX, THICKNESS_M, AggregatedPairs, PairSettings, build_pairs
from rfir_stages.model.predict import FLOOR_DB
from rfir_stages.model.residual import (FORMS, INTERPOLATION, ResidualConfig, ResidualFit, fit_gaussian, fit_smooth,
                                        link_coords, physics_db, residual_folds, training_spacing_deg,
                                        half_spacing_length_deg, visible_lengths)
from rfir_stages.model.surfels import surfel_areas

SHARINGS = ("auto", "label", "class", "segment", "global")
EDGES = "+edges"     # a candidate's name suffix: its model includes the edge waves (rfir_stages.model.edges)
LOSSES = ("db_mse", "db_huber")
FIT_KEYS = ("iterations", "start_iterations", "lr", "fit_gain", "half_space", "sigma_exponent", "reflection_ranges")
RESIDUAL_LISTS = {"residual_weights": "weights", "residual_lengths_deg": "lengths_deg",
                  "residual_sector_lengths_deg": "sector_lengths_deg",
                  "residual_range_lengths": "range_lengths", "residual_gaussian_weights": "gaussian_weights"}


def mae_db(pred_db: np.ndarray, meas_db: np.ndarray) -> float:
    """Mean absolute error in dB over finite entries (NaN when there is none)."""
    d = np.abs(np.asarray(pred_db) - np.asarray(meas_db))
    return float(np.mean(d[np.isfinite(d)])) if np.isfinite(d).any() else float("nan")


def between_training_links(protocol: str, aspect_deg) -> bool:
    """Whether the protocol's test aspects lie between training ones (data, every-N), where the residual
    takes its length from the training spacing (ResidualConfig.interpolation); not a held-out sector or
    range, nor links without aspects."""
    return aspect_deg is not None and protocol.partition(":")[0] not in ("sector", "range")


def residual_config(table: dict) -> ResidualConfig:
    """The residual settings of the [rf_fit.physical] table (ConfigError naming the key when wrong)."""
    form = str(table.get("residual", "auto"))
    if form not in FORMS:
        raise ConfigError(f"rf_fit.physical.residual = {form!r}: expected one of {', '.join(FORMS)}")
    raw = table.get("residual_weight", "auto")
    try:
        weight = None if raw == "auto" else float(raw)
    except (TypeError, ValueError):
        weight = -1.0
    if weight is not None and not weight > 0:
        raise ConfigError(f"rf_fit.physical.residual_weight = {raw!r}: expected \"auto\" or a number > 0 "
                          "(inf: the physics alone)")
    interpolation = str(table.get("residual_interpolation", "half-spacing"))
    if interpolation not in INTERPOLATION:
        raise ConfigError(f"rf_fit.physical.residual_interpolation = {interpolation!r}: expected one of "
                          f"{', '.join(INTERPOLATION)}")
    kw = {"form": form, "weight": weight, "interpolation": interpolation}
    for key, name in RESIDUAL_LISTS.items():
        if key in table:
            vals = [float(v) for v in table[key]]
            if not vals or min(vals) <= 0:
                raise ConfigError(f"rf_fit.physical.{key} = {table[key]!r}: expected a list of numbers > 0")
            kw[name] = tuple(vals)
    if "residual_iterations" in table:
        kw["iterations"] = int(table["residual_iterations"])
    return ResidualConfig(**kw)


def edge_waves_mode(table: dict):
    """rf_fit.physical.edge_waves: "auto" (chosen by validation), True ("on", "true") or False ("off",
    "false"); ConfigError naming the key otherwise."""
    mode = table.get("edge_waves", "auto")
    words = {"auto": "auto", "on": True, "true": True, "off": False, "false": False}
    if isinstance(mode, str) and mode.lower() in words:
        return words[mode.lower()]
    if isinstance(mode, bool):
        return mode
    raise ConfigError(f"rf_fit.physical.edge_waves = {mode!r}: expected \"auto\", \"on\" or \"off\"")


def split_candidate(candidate: str) -> tuple[str, bool]:
    """(material sharing, edge waves) of a candidate's name ("class", "global+edges", ...)."""
    return (candidate[:-len(EDGES)], True) if candidate.endswith(EDGES) else (candidate, False)


SELECTION_RULES = ("one_se", "lowest")


def selection_rule(table: dict) -> str:
    """rf_fit.physical.selection: how validation picks the material sharing (configs/rf_fit.toml)."""
    rule = str(table.get("selection", "one_se"))
    if rule not in SELECTION_RULES:
        raise ConfigError(f"rf_fit.physical.selection = {rule!r}: expected one of {', '.join(SELECTION_RULES)}")
    return rule


def physical_config(config: dict, render_cfg) -> tuple[PhysicalFitConfig, PairSettings, dict]:
    """(fit settings, pair settings, the [rf_fit.physical] table) from the [rf_fit] table."""
    table = dict(config.get("physical", {}))
    sharing = str(table.get("sharing", "auto"))
    if sharing not in SHARINGS:
        raise ConfigError(f"rf_fit.physical.sharing = {sharing!r}: expected one of {', '.join(SHARINGS)}")
    pol = str(table.get("polarisation", "V")).upper()
    if pol not in POLARISATIONS:
        raise ConfigError(f"rf_fit.physical.polarisation = {pol!r}: expected one of {', '.join(POLARISATIONS)}")
    loss = str(config.get("loss", "db_mse"))
    if loss not in LOSSES:
        raise ConfigError(f"rf_fit.loss = {loss!r}: expected one of {', '.join(LOSSES)}")
    fit_cfg = PhysicalFitConfig(**{k: table[k] for k in FIT_KEYS if k in table}, loss=loss,
                                huber_db=float(config.get("huber_db", 1.0)))
    pairs = PairSettings(visibility=bool(render_cfg.visibility), opacity=float(render_cfg.visibility_opacity),
                         margin_m=float(table.get("self_shadow_margin_m", 0.0025)), t_stop=float(render_cfg.t_stop),
                         colocated_tol_m=float(render_cfg.colocated_tol_m), polarisation=pol,
                         second_order=bool(table.get("second_order", True)),
                         third_order=bool(table.get("third_order", True)),
                         min_patch_area_m2=float(table.get("min_patch_area_m2", 2e-3)),
                         lit_threshold=float(table.get("lit_threshold", 0.2)),
                         edge_waves=edge_waves_mode(table) is not False)   # traced unless off; candidates choose
    residual_config(table)   # refused here, before any tracing, when wrong
    selection_rule(table)
    return fit_cfg, pairs, table


def sharing_candidates(table: dict, num_labels: int, num_classes: int | None = None) -> list[str]:
    """Material sharings to try: "auto" -> per object class (label_class_names: brick_03 -> brick; per
    segment without labels) and one global, chosen by validation; with a single class that is the
    global material, so only that is fitted. num_labels / num_classes: distinct object labels / label
    classes of the Gaussians (0: unlabelled; classes default to the labels)."""
    sharing = str(table.get("sharing", "auto"))
    classes = num_labels if num_classes is None else num_classes
    if sharing == "auto":
        base = ["global"] if num_labels and classes == 1 else ["class" if num_labels else "segment", "global"]
    elif sharing in ("label", "class") and not num_labels:
        raise ConfigError(f"rf_fit.physical.sharing = '{sharing}' needs gaussians/labels in the scene; "
                          "use 'segment' (materials from clustering the Gaussians) or 'global'")
    else:
        base = [sharing]
    mode = edge_waves_mode(table)   # "auto": each sharing with and without the edge waves, chosen by validation
    return base + [b + EDGES for b in base] if mode == "auto" else [b + EDGES for b in base] if mode else base


@dataclass
class PhysicalSetup:
    """Traced pair geometry of every training link, and each sharing's aggregated form."""

    geom: object
    labels: torch.Tensor | None
    pairs: object
    areas_m2: torch.Tensor
    num_segments: int
    seed: int
    trace_s: float
    label_names: list | None = None
    aggregated: dict = field(default_factory=dict)    # sharing -> (AggregatedPairs, index [G], names)
    residual_cfg: ResidualConfig = field(default_factory=ResidualConfig)
    agg_chunk: int = 1 << 20                          # pairs per chunk when aggregating (fewer for a band)
    extra_attrs: dict = field(default_factory=dict)   # more model attributes for the artifact (a band's)

    @staticmethod
    def trace(geom, links, ant, provider, settings: PairSettings, labels, table: dict, seed: int,
              label_names: list | None = None) -> "PhysicalSetup":
        t0 = time.time()
        areas = surfel_areas(geom.means, geom.log_scales, geom.rotations, geom.normals)
        pairs = build_pairs(geom, links, ant, ant, provider, settings, areas, labels=labels)
        return PhysicalSetup(geom, labels, pairs, areas, int(table.get("num_segments", 8)), seed, time.time() - t0,
                             label_names, residual_cfg=residual_config(table))

    def for_sharing(self, sharing: str):
        """(aggregated pairs, material of each Gaussian [G], material names) of a candidate (split_candidate)."""
        if sharing not in self.aggregated:
            base, edges = split_candidate(sharing)
            idx, names = material_index(base, self.geom.num, self.labels, self.geom.means, self.geom.normals,
                                        self.num_segments, self.seed, self.label_names)
            self.aggregated[sharing] = (AggregatedPairs.build(self.pairs, idx, len(names), chunk=self.agg_chunk,
                                                              edge_waves=edges), idx, names)
        return self.aggregated[sharing]

    def pairs_for(self, sharing: str):
        """The traced pairs as the candidate's model sees them (without the edge items unless it has them)."""
        return self.pairs if split_candidate(sharing)[1] else dataclasses.replace(self.pairs, edges=None)

    def fit(self, sharing: str, rows: np.ndarray | None, target_db: np.ndarray, cfg: PhysicalFitConfig,
            progress) -> PhysicalFitResult:
        agg, _, names = self.for_sharing(sharing)
        if rows is not None:
            agg = agg.select_links(rows)
        return fit_materials(agg, len(names), target_db, cfg, progress, label=f"physical/{sharing}")

    def predict_db(self, sharing: str, rows: np.ndarray, params) -> np.ndarray:
        agg, _, _ = self.for_sharing(sharing)
        with torch.no_grad():   # links that see no lit surfel score at the prediction floor, never at -3000 dB
            power = agg.select_links(rows).power(params.values(), params.gain_db).numpy()
        return np.maximum(10 * np.log10(np.maximum(power, 1e-300)), FLOOR_DB)

    def fit_residual(self, sharing: str, result: PhysicalFitResult, target_db: np.ndarray, tx_m: np.ndarray,
                     rx_m: np.ndarray, protocol: str, aspect_deg: np.ndarray | None, range_m: np.ndarray | None,
                     progress) -> ResidualFit:
        """The residual on top of the fitted materials (held fixed), chosen by validation on the training
        rows (target_db [M, K]; tx/rx [M, 3] m; aspect/range of those rows); the physics alone is a
        candidate and its validation MAE is reported."""
        cfg = self.residual_cfg
        if cfg.form == "off" or (cfg.weight is not None and not np.isfinite(cfg.weight)):
            return ResidualFit("off", chosen="physics only (rf_fit.physical.residual)")
        _, idx, _ = self.for_sharing(sharing)
        with torch.no_grad():
            vals = result.params.values()
            gain = float(result.params.gain_db)
        pairs = self.pairs_for(sharing)
        phys = physics_db(pairs, idx, vals, gain)
        folds, how = residual_folds(protocol, aspect_deg, range_m, len(target_db))
        lengths_key = "residual_lengths_deg"
        if protocol.partition(":")[0] == "sector":   # into unmeasured aspects: the shorter lengths (configs/rf_fit.toml)
            cfg = dataclasses.replace(cfg, lengths_deg=cfg.sector_lengths_deg)
            lengths_key = "residual_sector_lengths_deg"
        if cfg.form != "gaussian":
            centre = 0.5 * (self.geom.means.min(0).values + self.geom.means.max(0).values).numpy()
            coords = link_coords(tx_m, rx_m, centre)
            spacing = None
            if cfg.interpolation == "half-spacing" and between_training_links(protocol, aspect_deg):
                spacing = training_spacing_deg(aspect_deg)
            if spacing is None:
                how += f"; lengths {', '.join(f'{v:g}' for v in cfg.lengths_deg)} deg ({lengths_key})"
            else:
                shown = ", ".join(f"{v:g}" for v in visible_lengths(cfg, spacing))
                offered = (f"validated lengths {shown} deg (none shorter than half the spacing)" if shown else
                           "no validated lengths (every one of residual_lengths_deg is shorter than half the spacing)")
                how += (f"; length {half_spacing_length_deg(cfg, spacing):.3g} deg (half the training spacing "
                        f"{spacing:.3g} deg, at most the longest of residual_lengths_deg) and the smallest weight "
                        f"unless a validated candidate beats it (residual_interpolation); {offered}")
            fit = fit_smooth(coords, phys, target_db, folds, cfg, how, spacing_deg=spacing)
        else:
            fit = fit_gaussian(pairs, idx, vals, gain, self.geom.num, phys, target_db, folds, cfg, how)
        best = min(fit.validation.values())
        progress.log(f"rf-fit: residual ({cfg.form}) validation MAE on {sum(len(f) for f in folds)} training links "
                     f"({how}): physics only {fit.validation['physics only']:.2f} dB, best {best:.2f} dB, "
                     f"chosen {fit.validation[fit.chosen]:.2f} dB -> "
                     f"{fit.chosen} ({fit.wall_time_s:.0f} s)")
        return fit

    def unseen_materials(self, sharing: str) -> list[str]:
        """Materials no training link sees (they keep their starting values)."""
        agg, _, names = self.for_sharing(sharing)
        seen = (agg.a_te.abs().sum((0, 2, 3)) + agg.a_tm.abs().sum((0, 2, 3))) > 0
        return [n for n, s in zip(names, seen.tolist()) if not s]


def material_table(result: PhysicalFitResult, names: list[str], freqs_hz: np.ndarray) -> list[dict]:
    """One row per fitted material: eps_r, sigma at the first frequency, S, thickness, |Gamma| at normal incidence."""
    with torch.no_grad():
        vals = result.params.values()
    f = torch.as_tensor(np.asarray(freqs_hz, np.float64))
    r = vals.normal_reflection(f).abs().detach().numpy()
    sigma = power_law(vals.sigma_1ghz[:, None], vals.sigma_exponent, f[None]).detach().numpy()
    th = None if vals.thickness_m is None else vals.thickness_m.detach().numpy()
    return [{"material": n, "eps_r": float(vals.eps_r[i]), "sigma_s_per_m": float(sigma[i, 0]),
             "scattering": float(vals.scattering[i]), "thickness_m": 0.0 if th is None else float(th[i]),
             "gamma_normal_abs": [float(x) for x in r[i]]} for i, n in enumerate(names)]


def attach_ranges(rows: list[dict], ranges) -> None:
    """Add to each material row (material_table / room material_rows dicts) its "gamma_normal_range"
    [low, high] from ranges [N, 2] (fit_physical.reflection_ranges; None: nothing added)."""
    for row, span in zip(rows, [] if ranges is None else ranges):
        row["gamma_normal_range"] = [float(span[0]), float(span[1])]


def range_words(row: dict) -> str:
    """" (links allow lo-hi)" for a material row with its range (", not determined by the links" added where
    it is wide: identifiability.range_note), else ""."""
    span = row.get("gamma_normal_range")
    if span is None:
        return ""
    note = range_note(*span)
    return f" (links allow {span[0]:.2f}-{span[1]:.2f}{', ' + note if note else ''})"


def bound_warnings(rows: list[dict]) -> list[str]:
    """Warnings for fitted materials at the edge of their range (the data ask for something the model
    cannot be): eps_r or thickness within 2 % of its upper bound. rows: material_table's dicts."""
    return [f"{r['material']}: eps_r {r['eps_r']:.1f} / thickness {r['thickness_m']:.2f} m ran to the bound of its "
            "range" for r in rows if r["eps_r"] > 0.98 * EPS_R_MAX or r["thickness_m"] > 0.98 * THICKNESS_M[1]]


def residual_training_attrs(fit: ResidualFit) -> dict:
    """Training attributes of the residual: its form, the chosen candidate and every candidate's
    validation MAE (the physics alone among them)."""
    out = {"residual_form": fit.form, "residual_chosen": fit.chosen, "residual_validation": fit.how,
           "residual_time_s": float(fit.wall_time_s)}
    if fit.validation:
        out["residual_val_mae_physics_only_db"] = float(fit.validation["physics only"])
        out["residual_val_mae_db"] = float(fit.validation[fit.chosen])
        out["residual_candidates"] = "; ".join(f"{k}: {v:.3f} dB" for k, v in fit.validation.items())
    return out


def physical_artifact_fields(setup: PhysicalSetup, sharing: str, result: PhysicalFitResult, freqs_hz: np.ndarray,
                             settings: PairSettings, residual: ResidualFit | None = None, tx_m=None, rx_m=None
                             ) -> tuple[dict, dict]:
    """(datasets, model attributes) for the rf artifact (rfir_stages.model.artifact); residual: fitted
    on the training links tx_m / rx_m [M, 3] m."""
    _, idx, names = setup.for_sharing(sharing)
    settings = dataclasses.replace(settings, edge_waves=split_candidate(sharing)[1])   # the candidate's model
    data, attrs = physical_fields(result.params.values(), idx, setup.areas_m2, freqs_hz, settings, names,
                                  float(result.params.gain_db.detach()), residual, tx_m, rx_m)
    attrs.update(setup.extra_attrs)
    return data, attrs
