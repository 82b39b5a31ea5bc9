"""rf-fit with the physical model (rfir_stages.model): candidates, validation fits, the artifact.

The geometry of every (training link, lit surfel) pair is traced once (`PhysicalSetup`); each
material sharing ("label", "segment", "global") sums it into its aggregated form once, and fits on
any subset of the training links then cost links x materials x angle nodes per step.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from rfir_cli.errors import ConfigError
from rfir_stages.model.artifact import physical_fields
from rfir_stages.model.fit_physical import PhysicalFitConfig, PhysicalFitResult, fit_materials, material_index
from rfir_stages.model.physical import EPS_R_MAX, POLARISATIONS, THICKNESS_M, AggregatedPairs, PairSettings, build_pairs
from rfir_stages.model.predict import FLOOR_DB
from rfir_stages.model.surfels import surfel_areas

SHARINGS = ("auto", "label", "segment", "global")
FIT_KEYS = ("iterations", "start_iterations", "lr", "fit_gain", "half_space", "sigma_exponent")


def physical_config(config: dict, render_cfg) -> tuple[PhysicalFitConfig, PairSettings, dict]:
    """(fit settings, pair settings, the [rf_fit.physical] table) from the [rf_fit] table."""
    table = dict(config.get("physical", {}))
    sharing = str(table.get("sharing", "auto"))
    if sharing not in SHARINGS:
        raise ConfigError(f"rf_fit.physical.sharing = {sharing!r}: expected one of {', '.join(SHARINGS)}")
    pol = str(table.get("polarisation", "V")).upper()
    if pol not in POLARISATIONS:
        raise ConfigError(f"rf_fit.physical.polarisation = {pol!r}: expected one of {', '.join(POLARISATIONS)}")
    fit_cfg = PhysicalFitConfig(**{k: table[k] for k in FIT_KEYS if k in table},
                                loss=str(config.get("loss", "db_mse")) if config.get("loss") != "paper" else "db_mse",
                                huber_db=float(config.get("huber_db", 1.0)))
    pairs = PairSettings(visibility=bool(render_cfg.visibility), opacity=float(render_cfg.visibility_opacity),
                         margin_m=float(table.get("self_shadow_margin_m", 0.0025)), t_stop=float(render_cfg.t_stop),
                         colocated_tol_m=float(render_cfg.colocated_tol_m), polarisation=pol,
                         second_order=bool(table.get("second_order", True)),
                         min_patch_area_m2=float(table.get("min_patch_area_m2", 2e-3)))
    return fit_cfg, pairs, table


def sharing_candidates(table: dict, has_labels: bool) -> list[str]:
    """Material sharings to try: "auto" -> per label (or per segment without labels) and one global."""
    sharing = str(table.get("sharing", "auto"))
    if sharing == "auto":
        return ["label" if has_labels else "segment", "global"]
    if sharing == "label" and not has_labels:
        raise ConfigError("rf_fit.physical.sharing = 'label' needs gaussians/labels in the scene; "
                          "use 'segment' (materials from clustering the Gaussians) or 'global'")
    return [sharing]


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

    @staticmethod
    def trace(geom, links, ant, provider, settings: PairSettings, labels, table: dict, seed: int,
              label_names: list | None = None) -> "PhysicalSetup":
        t0 = time.time()
        areas = surfel_areas(geom.means, geom.log_scales, geom.rotations, geom.normals)
        pairs = build_pairs(geom, links, ant, ant, provider, settings, areas, labels=labels)
        return PhysicalSetup(geom, labels, pairs, areas, int(table.get("num_segments", 8)), seed, time.time() - t0,
                             label_names)

    def for_sharing(self, sharing: str):
        if sharing not in self.aggregated:
            idx, names = material_index(sharing, self.geom.num, self.labels, self.geom.means, self.geom.normals,
                                        self.num_segments, self.seed, self.label_names)
            self.aggregated[sharing] = (AggregatedPairs.build(self.pairs, idx, len(names)), idx, names)
        return self.aggregated[sharing]

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
    sigma = (vals.sigma_1ghz[:, None] * (f[None] / 1e9) ** vals.sigma_exponent).detach().numpy()
    th = None if vals.thickness_m is None else vals.thickness_m.detach().numpy()
    return [{"material": n, "eps_r": float(vals.eps_r[i]), "sigma_s_per_m": float(sigma[i, 0]),
             "scattering": float(vals.scattering[i]), "thickness_m": 0.0 if th is None else float(th[i]),
             "gamma_normal_abs": [float(x) for x in r[i]]} for i, n in enumerate(names)]


def bound_warnings(rows: list[dict]) -> list[str]:
    """Warnings for fitted materials at the edge of their range (the data ask for something the model
    cannot be): eps_r or thickness within 2 % of its upper bound. rows: material_table's dicts."""
    return [f"{r['material']}: eps_r {r['eps_r']:.1f} / thickness {r['thickness_m']:.2f} m ran to the bound of its "
            "range" for r in rows if r["eps_r"] > 0.98 * EPS_R_MAX or r["thickness_m"] > 0.98 * THICKNESS_M[1]]


def physical_artifact_fields(setup: PhysicalSetup, sharing: str, result: PhysicalFitResult, freqs_hz: np.ndarray,
                             settings: PairSettings) -> tuple[dict, dict]:
    """(datasets, model attributes) for the rf artifact (rfir_stages.model.artifact)."""
    _, idx, names = setup.for_sharing(sharing)
    return physical_fields(result.params.values(), idx, setup.areas_m2, freqs_hz, settings, names,
                           float(result.params.gain_db.detach()))
