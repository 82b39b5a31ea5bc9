"""Load a fitted RSSI model from an `rf` artifact and predict path gain for any links.

`RssiPredictor(rf)` rebuilds rssi_model.RssiModel (materials, LoS network, gains) and the probe
field from the artifact's model/ group; `path_gain_db(tx, rx)` traces V once per distinct
transmitter and the direct-path segments, then renders in chunks of links (memory ~ chunk x G).
"""
from __future__ import annotations

import numpy as np
import torch

from rfir_cli.errors import SchemaError
from rfir_stages.rf_fit.antennas import AntennaPattern
from rfir_stages.rf_fit.links import geometry_from_artifact
from rfir_stages.rf_fit.occlusion import make_provider
from rfir_stages.rf_fit.rssi_fit import unique_rows
from rfir_stages.rf_fit.rssi_model import (ProbeField, RssiModel, link_terms, los_transmittance, point_transmittance,
                                           predict_db)

BYTES_PER_LINK_GAUSSIAN = 96  # working set of one chunk: float64 geometry temporaries + cached terms


def _logit(p: np.ndarray) -> torch.Tensor:
    p = np.clip(np.asarray(p, np.float64), 1e-9, 1 - 1e-9)
    return torch.as_tensor(np.log(p / (1 - p)))


class RssiPredictor:
    """A fitted RSSI model ready to predict (no gradients)."""

    def __init__(self, rf, occlusion: str = "auto"):
        attrs = rf.free.get("model@attrs", {})
        model = rf.free.get("model", {})
        if str(attrs.get("model_kind", "")) != "rssi_los_nlos" or "probe_values" not in model:
            raise SchemaError("not an RSSI model (fit it on task 'rssi' measurements with `rfir rf-fit`)", path=rf.path)
        self.rf = rf
        self.geom = geometry_from_artifact(rf)
        self.freq_hz = float(np.asarray(rf["rf/freq_hz"])[0])
        self.margin = float(attrs.get("render.self_shadow_margin_m", 0.01))
        self.t_stop = float(attrs.get("render.t_stop", 1e-4))
        self.alpha_min = float(attrs.get("render.alpha_min", 1e-3))
        self.vis_opacity = torch.full((self.geom.num,), float(attrs.get("render.visibility_opacity", 0.9)),
                                      dtype=torch.float64)
        self.antenna = AntennaPattern(str(attrs.get("antenna_kind", "isotropic")))
        self.weighting = bool(attrs.get("weighting", True))
        self.model = self._model(model, int(attrs.get("hidden", 16)))
        shape = tuple(int(x) for x in model["probe_shape"])
        self.field = ProbeField(np.asarray(model["probe_origin_m"], np.float64), float(attrs.get("probe_step_m", 0.5)),
                                shape, torch.as_tensor(np.asarray(model["probe_values"], np.float32)))
        self.provider = make_provider(occlusion, self.geom, self.alpha_min)

    def _model(self, model: dict, hidden: int) -> RssiModel:
        g = self.geom.num
        m = RssiModel(torch.arange(g), weighting=self.weighting, hidden=hidden)
        rf = self.rf
        with torch.no_grad():
            m.rf.theta_a.copy_(_logit(rf["rf/opacity"]))
            r = np.asarray(rf["rf/roughness"], np.float64) - 1.0
            m.rf.theta_r.copy_(torch.as_tensor(np.where(r > 30, r, np.log(np.expm1(np.maximum(r, 1e-12))))))
            m.rf.theta_g.copy_(_logit(rf["rf/gamma_abs"]))
            m.rf.theta_phi.copy_(torch.as_tensor(np.asarray(rf["rf/gamma_phase_rad"], np.float64)))
            m.rf.s_tx_db.copy_(torch.as_tensor(np.asarray(model["s_tx_db"], np.float64)[:1]))
            m.nlos_gain_db.fill_(float(np.asarray(model["nlos_gain_db"]).reshape(-1)[0]))
            state = {k[len("los."):]: torch.as_tensor(np.asarray(v)) for k, v in model.items() if k.startswith("los.")}
            m.los.load_state_dict(state)
        return m

    def memory_estimate_bytes(self, num_links: int, chunk_links: int) -> int:
        """Peak memory of `path_gain_db` for num_links links: one chunk's [chunk, G] working set plus
        the per-receiver transmittances [R, G] float32 and the link arrays."""
        g = self.geom.num
        return int(min(num_links, chunk_links) * g * BYTES_PER_LINK_GAUSSIAN + num_links * g * 4 + num_links * 200)

    def path_gain_db(self, tx_m: np.ndarray, rx_m: np.ndarray, chunk_links: int = 512, progress=None) -> np.ndarray:
        """Predicted path gain [N] dB for links tx_m / rx_m [N, 3] m."""
        tx_m, rx_m = np.array(tx_m, np.float64), np.array(rx_m, np.float64)   # writable copies for torch
        out = np.empty(len(tx_m))
        with torch.no_grad():
            tx_u, tx_i = unique_rows(tx_m)
            rx_u, rx_i = unique_rows(rx_m)
            v_tx = point_transmittance(self.provider, self.geom, tx_u, self.vis_opacity, self.margin, self.t_stop)
            tbar = self.field.at(rx_u)
            los_v = los_transmittance(self.provider, torch.as_tensor(tx_m), torch.as_tensor(rx_m), self.vis_opacity,
                                      self.margin)
            for a in range(0, len(tx_m), chunk_links):
                b = min(len(tx_m), a + chunk_links)
                terms = link_terms(self.geom, torch.as_tensor(tx_m[a:b]), torch.as_tensor(rx_m[a:b]), self.freq_hz, v_tx,
                                   tx_i[a:b], tbar, rx_i[a:b], los_v[a:b], self.antenna)
                out[a:b] = predict_db(terms, self.model).numpy()
                if progress is not None:
                    progress.advance(b - a)
        return out


def load_predictor(rf, occlusion: str = "auto"):
    """The predictor of an RSSI `rf` artifact: the physical room model (model_kind "rssi_physical") or
    the LoS/NLoS model."""
    if str(rf.free.get("model@attrs", {}).get("model_kind", "")) == "rssi_physical":
        from rfir_stages.model.room import RoomPredictor
        return RoomPredictor(rf, occlusion)
    return RssiPredictor(rf, occlusion)
