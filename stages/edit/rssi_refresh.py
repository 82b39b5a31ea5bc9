"""Edited RSSI models: the receiver-side probe field follows the edited geometry.

An RSSI model (docs/rssi.md) stores `model/probe_values` [P, G]: the transmittance from a lattice
of probe points to every Gaussian's mean, traced with the frozen visibility opacity. It depends
on the geometry, so after an edit it is traced again on the edited Gaussians (same lattice step,
opacity, margin and t_stop as the fit); leaving the old one would pair stale (or, after a delete
or duplicate, wrongly sized) transmittances with the edited scene.
"""
from __future__ import annotations

import numpy as np
import torch

from rfir_stages.rf_fit.occlusion import FrozenGeometry, make_provider
from rfir_stages.rf_fit.rssi_model import build_probe_field


def is_rssi_model(model_attrs: dict) -> bool:
    return str(model_attrs.get("model_kind", "")) == "rssi_los_nlos"


def refreshed_probe_field(arrays: dict, model_attrs: dict) -> dict:
    """New `model/probe_*` datasets for the edited Gaussians in `arrays` (gaussians/* [G', ...])."""
    t = lambda k: torch.as_tensor(np.asarray(arrays[f"gaussians/{k}"]), dtype=torch.float64)  # noqa: E731
    geom = FrozenGeometry(t("means"), t("log_scales"), t("rotations"), t("normals"))
    alpha_min = float(model_attrs.get("render.alpha_min", 1e-3))
    opacity = torch.full((geom.num,), float(model_attrs.get("render.visibility_opacity", 0.9)), dtype=torch.float64)
    field = build_probe_field(make_provider("auto", geom, alpha_min), geom, float(model_attrs.get("probe_step_m", 0.5)),
                              opacity, float(model_attrs.get("render.self_shadow_margin_m", 0.01)),
                              float(model_attrs.get("render.t_stop", 1e-4)))
    return {"probe_values": field.values.numpy(), "probe_origin_m": np.asarray(field.origin, np.float64),
            "probe_shape": np.asarray(field.shape, np.int64)}
