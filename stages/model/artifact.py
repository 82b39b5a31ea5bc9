"""The physical model in an `rf` artifact: one writer (`physical_fields`) and one loader (`load_physical`).

It is rfir's one fitted radio model (RCS, a band, and the room model for RSSI, which adds its own
attributes). An rf artifact without it (the retired per-Gaussian family) is refused by the schema
(rfir_core.schema, kind "rf") when read, and by `require_physical` here.

Datasets (schema: rfir_core.schema, kind "rf"; N materials, G Gaussians, F fitted frequencies):
- material/index [G] int: material of each Gaussian;
- material/area_m2 [G]: surfel area A_l (surfels.surfel_areas, kept so prediction uses the same);
- material/eps_r, material/sigma_1ghz_s_per_m, material/scattering, material/thickness_m [N]
  (thickness 0: a half-space);
- material/gamma_normal_abs [N, F]: |R_TE| at normal incidence at each fitted frequency;
- rf/gamma_abs, rf/gamma_phase_rad [G]: each Gaussian's material's normal-incidence coefficient at
  the first fitted frequency (what attribute maps show); rf/opacity [G]: the RF opacity of the
  traced visibility; rf/roughness [G]: 1 (no lobe exponent in this model).
- residual/* (residual.py): the smooth / blend form's training links residual/tx_pos,
  residual/rx_pos [T, 3], weights residual/weights_db [T, F], mean residual/mean_db [F] and the floor under
  the physics residual/floor_db [F]; or the
  gaussian form's factor residual/surfel [G, 2] (real, imaginary parts).
Attributes of group model: family = "physical", sigma_exponent, polarisation, gain_db,
material_names, the PairSettings (pairs.*) and the residual's residual.form ("off", "smooth",
"blend", "gaussian"), residual.chosen, residual.weight, residual.length_deg, residual.range_length.
The room model (rf_fit.room_stage) adds to group model its device gains (device_<side>_*), and its residual terms
in dB where rf-fit kept some (residual_terms.ResidualTerms.table / attrs: residual_terms_* fields, the attribute
residual_terms naming them, "off" or absent: none), which RoomRadioModel applies.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
import torch

from rfir_core.errors import SchemaError
from rfir_core.schema import get_kind

from .physical import MaterialValues, PairSettings
from .residual import ResidualFit, load_residual, residual_fields

FAMILY = "physical"


def is_physical_model(rf) -> bool:
    return str(rf.free.get("model@attrs", {}).get("family", "")) == FAMILY


def require_physical(rf) -> None:
    """SchemaError (one line naming the file) unless `rf` holds the physical model."""
    if not is_physical_model(rf):
        raise SchemaError(get_kind("rf").retired[1], path=rf.path)


def physical_fields(mats: MaterialValues, material_of_gaussian: torch.Tensor, areas_m2: torch.Tensor,
                    freqs_hz: np.ndarray, settings: PairSettings, names: list[str], gain_db: float,
                    residual: ResidualFit | None = None, train_tx_m=None, train_rx_m=None) -> tuple[dict, dict]:
    """(datasets, model attributes) of a fitted physical model (see the module docstring); residual:
    fitted on the training links train_tx_m / train_rx_m [T, 3] m (None: none)."""
    idx = np.asarray(material_of_gaussian, dtype=np.int64)
    f = torch.as_tensor(np.asarray(freqs_hz, dtype=np.float64))
    r_normal = mats.normal_reflection(f).detach().numpy()                      # [N, F]
    th = mats.thickness_m
    data = {
        "material/index": idx,
        "material/area_m2": np.asarray(areas_m2, dtype=np.float64),
        "material/eps_r": mats.eps_r.detach().numpy().copy(),
        "material/sigma_1ghz_s_per_m": mats.sigma_1ghz.detach().numpy().copy(),
        "material/scattering": mats.scattering.detach().numpy().copy(),
        "material/thickness_m": np.zeros(len(names)) if th is None else th.detach().numpy().copy(),
        "material/gamma_normal_abs": np.abs(r_normal),
        "rf/opacity": np.full(len(idx), settings.opacity),
        "rf/roughness": np.ones(len(idx)),
        "rf/gamma_abs": np.abs(r_normal[idx, 0]),
        "rf/gamma_phase_rad": np.angle(r_normal[idx, 0]),
    }
    attrs = {"family": FAMILY, "sigma_exponent": mats.sigma_exponent, "gain_db": float(gain_db),
             "material_names": np.asarray(names, dtype=object),
             "model_doc": "surfel physical optics with physical materials (docs/physics.md section 8)"}
    attrs.update({f"pairs.{fl.name}": getattr(settings, fl.name) for fl in fields(PairSettings)})
    r_data, r_attrs = residual_fields(residual or ResidualFit("off"), train_tx_m, train_rx_m)
    data.update(r_data)
    attrs.update(r_attrs)
    return data, attrs


def has_residual(rf) -> bool:
    """A physical model with a residual on top (residual.py)."""
    return is_physical_model(rf) and str(rf.free.get("model@attrs", {}).get("residual.form", "off")) != "off"


@dataclass
class PhysicalModel:
    """A loaded physical model: materials, each Gaussian's material [G], areas [G] m^2, settings, the
    residual on top (form "off": none)."""

    mats: MaterialValues
    material_of_gaussian: torch.Tensor
    areas_m2: torch.Tensor
    settings: PairSettings
    gain_db: float
    names: list
    residual: ResidualFit


def load_physical(rf) -> PhysicalModel:
    """The physical model of an `rf` artifact written with `physical_fields`."""
    require_physical(rf)
    attrs = rf.free.get("model@attrs", {})
    t = lambda k: torch.as_tensor(np.asarray(rf[k], dtype=np.float64))  # noqa: E731
    th = t("material/thickness_m")
    mats = MaterialValues(t("material/eps_r"), t("material/sigma_1ghz_s_per_m"), float(attrs.get("sigma_exponent", 1.0)),
                          t("material/scattering"), None if bool((th <= 0).all()) else th.clamp(min=1e-6))
    defaults = PairSettings()
    kw = {fl.name: type(getattr(defaults, fl.name))(attrs[f"pairs.{fl.name}"])     # bool, int, float or str
          for fl in fields(PairSettings) if f"pairs.{fl.name}" in attrs}
    names = [str(s) for s in np.atleast_1d(attrs.get("material_names", []))]
    gain = float(attrs.get("gain_db", 0.0))
    return PhysicalModel(mats, torch.as_tensor(np.asarray(rf["material/index"], dtype=np.int64)),
                         t("material/area_m2"), PairSettings(**kw), gain if math.isfinite(gain) else 0.0, names,
                         load_residual(rf))
