"""The object RCS model kind: path gain predicted by the physical model of an `rf` artifact that rf-fit wrote
from RCS (or band) measurements, surfel physical optics on the Gaussians (docs/physics.md section 8).

`ObjectRcsModel` (a radio_model_base.RadioModel) loads the artifact once (materials, antenna, geometry, the
occlusion provider, the planar patches of the double bounces and edge waves) and predicts any links at any
frequency: the material laws carry eps_r and sigma to it and the phases follow k. Frequencies outside
0.1-100 GHz (where ITU-R P.2040 laws are given) are predicted with a logged warning. Predicted power below
FLOOR_DB (links that see no lit surfel: a plate edge-on) is reported at FLOOR_DB, never as -inf or -3000 dB,
and counted in the log. Many frequencies (a band) are evaluated in frequency chunks, each link traced once;
above EXACT_MAX_FREQS of them with the fit's aggregated form (band.py). The artifact's residual
(residual.py) is applied on top: the gaussian form inside the field sum, the smooth and blend forms in dB
(zero at frequencies that were not fitted, said in the log).

`predict_physical_db` is the same for one call (it loads the artifact each time).
"""
from __future__ import annotations

import numpy as np
import torch

from rfir_core.progress import NullProgress

from .antenna_patterns import antenna_from_attrs
from .band import EXACT_MAX_FREQS, band_field, band_power
from .links import make_links, scene_centre
from .occlusion import make_provider
from .physical import build_pairs
from .radio_model_base import FLOOR_DB, RadioModel
from .residual import kernel_form_at
from .sampling import cell_size_m, coarse_surfels_warning
from .second_order import planar_patches
from .split_protocols import protocol_masks

VALID_GHZ = (0.1, 100.0)
BAND_EDGE_TOL = 1e-9  # relative tolerance on a band fit's edges


class ObjectRcsModel(RadioModel):
    """The physical model of an object fitted on RCS or band measurements (module docstring); settings:
    physical.PairSettings; the antenna pattern: `antenna` (boresight at the scene centre, as simulate aims it)."""

    kind = "rcs_physical"
    BYTES_PER_LINK = 400_000   # surfel pairs of a link and their coefficients, per frequency chunk

    def __init__(self, rf, occlusion: str = "auto"):
        super().__init__(rf, occlusion)
        model = self.physical
        self.settings = model.settings
        self.antenna = antenna_from_attrs(rf.free.get("model@attrs", {}))
        self.centre = scene_centre(self.geometry)
        self.visibility = make_provider(occlusion, self.geometry) if model.settings.visibility else None
        labels = rf.get("gaussians/labels")
        self.patches = planar_patches(self.geometry, model.areas_m2,
                                      None if labels is None else torch.as_tensor(np.asarray(labels)),
                                      model.settings.min_patch_area_m2) \
            if model.settings.second_order or model.settings.edge_waves else None
        self.link_task = self.task if self.task in ("rcs", "wideband") else "rcs"

    @property
    def provider(self):
        """The occlusion provider (the one the model traces visibility with, when it does)."""
        if self.visibility is not None:
            return self.visibility
        return super().provider

    def _wanted_freqs(self, measured_hz=None) -> np.ndarray:
        return band_default_freqs(self.artifact, measured_hz)

    def training_split(self, meas) -> np.ndarray | None:
        """0 training, 1 test, -1 unused per measured row, by the split protocol the model was fitted with."""
        protocol = str(self.artifact.free.get("training@attrs", {}).get("split", "data"))
        if protocol == "data" and meas.get("split") is None:
            return np.full(len(meas["tx_pos"]), -1)
        train, test = protocol_masks(meas, protocol, str(getattr(meas, "path", "measurements")))
        return np.where(test, 1, np.where(train, 0, -1))

    def _path_gain_db(self, tx, rx, freqs, progress, advance, chunk_links, physics_only):
        model = self.physical
        chunk_links = int(chunk_links or 64)
        outside = freqs[(freqs / 1e9 < VALID_GHZ[0]) | (freqs / 1e9 > VALID_GHZ[1])]
        if outside.size:
            progress.log(f"warning: {', '.join(f'{f / 1e9:g}' for f in outside)} GHz lies outside the range of the "
                         f"material laws ({VALID_GHZ[0]:g}-{VALID_GHZ[1]:g} GHz); predicted by extrapolating them")
        fitted = self.fitted_freqs_hz
        unfitted = [f for f in freqs if not np.any(np.abs(fitted - f) <= 1e-6 * f)]
        if unfitted and fitted.size == 1 and len(model.names) > 1:
            progress.log(f"predict: {len(model.names)} materials fitted at {fitted[0] / 1e9:g} GHz alone, predicted "
                         f"at {', '.join(f'{f / 1e9:g}' for f in unfitted[:4])} GHz: materials per label fitted at one "
                         "frequency carry over less well than one for the object")
        coarse = coarse_surfels_warning(cell_size_m(self.geometry.log_scales, self.geometry.rotations,
                                                    self.geometry.normals, model.areas_m2), freqs)
        if coarse:
            progress.log(f"warning: {coarse}")
        if model.settings.edge_waves:
            progress.log("predict: with the edge waves of the planar patches' outer edges (chosen at rf-fit; "
                         "docs/physics.md section 8.13)")
        res = model.residual
        surfel = res.params["surfel"] if res.form == "gaussian" else None
        gain = 10 ** (model.gain_db / 10)
        exact_max = EXACT_MAX_FREQS   # read at each call: tests lower it here to check the band form
        out = np.zeros((len(tx), len(freqs)))
        phys = np.zeros_like(out) if surfel is not None and physics_only else out
        if surfel is None and len(freqs) > exact_max:
            progress.log(f"predict: {len(freqs)} frequencies: the fit's aggregated form (reflection coefficients on "
                         "2-degree angle nodes; band.py)")
        with progress.task("predict (physical)", total=len(tx)) as bar, torch.no_grad():
            for a in range(0, len(tx), chunk_links):
                links = make_links(tx[a:a + chunk_links], rx[a:a + chunk_links], freqs, self.centre, self.link_task)
                pairs = build_pairs(self.geometry, links, self.antenna, self.antenna, self.visibility, model.settings,
                                    model.areas_m2, self.patches)
                for dest, factor in ((out, surfel), (phys, None)) if phys is not out else ((out, surfel),):
                    if factor is None and len(freqs) > exact_max:   # a band: the fit's aggregated form
                        power = band_power(pairs, model.material_of_gaussian, model.mats)
                    else:
                        field, diffuse = band_field(pairs, model.material_of_gaussian, model.mats,
                                                    surfel_factor=factor)
                        power = field.abs() ** 2 + diffuse
                    dest[a:a + chunk_links] = 10 * np.log10((power * gain).numpy() + 1e-300)
                bar.advance(links.num)
                if advance is not None:
                    advance(links.num)
        low = out < FLOOR_DB
        if low.any():
            progress.log(f"predict: {int(low.sum())} of {low.size} predicted path gains are below {FLOOR_DB:g} dB "
                         "(no lit surfel seen); reported at that floor")
        out, phys = np.maximum(out, FLOOR_DB), np.maximum(phys, FLOOR_DB)
        if res.form in ("smooth", "blend"):
            out, missing = kernel_form_at(res, tx, rx, self.centre.numpy(), phys, freqs, fitted)
            if missing:
                progress.log(f"predict: {', '.join(f'{f / 1e9:g}' for f in missing)} GHz was not fitted: the "
                             "physical model alone there (the residual is zero at frequencies it was not fitted at)")
            out = np.maximum(out, FLOOR_DB)
        if res.form != "off":
            progress.log(f"predict: residual {res.form} ({res.chosen}) applied on top of the physical model")
        return out, (phys if physics_only else None)


def band_default_freqs(rf, measured_hz=None) -> np.ndarray:
    """Frequencies [K] Hz an object model predicts when none are asked for: a band fit's whole band (the measured
    frequencies measured_hz inside it, or its num_freqs evenly spaced without them); otherwise the fitted ones."""
    attrs = rf.free.get("model@attrs", {})
    if "band.num_freqs" not in attrs:
        return np.asarray(rf["rf/freq_hz"], np.float64)
    lo, hi = float(attrs["band.f_min_hz"]), float(attrs["band.f_max_hz"])
    if measured_hz is None:
        return np.linspace(lo, hi, int(attrs["band.num_freqs"]))
    f = np.asarray(measured_hz, np.float64)
    return f[(f >= lo * (1 - BAND_EDGE_TOL)) & (f <= hi * (1 + BAND_EDGE_TOL))]


def predict_physical_db(rf, tx, rx, freqs, task: str = "rcs", *, occlusion: str = "auto", chunk_links: int = 64,
                        progress=None, with_physics_only: bool = False):
    """Path gain [L, K] dB for links tx/rx [L, 3] m at freqs [K] Hz of the object model in `rf`; with_physics_only:
    (that, the physical model's alone, without the residual).
    One call; a caller that predicts more than once keeps an ObjectRcsModel. task: the links' antenna aiming
    (boresight at the scene centre for "rcs"/"wideband")."""
    model = ObjectRcsModel(rf, occlusion)
    model.link_task = task
    full, physics = model.predict_with_physics_only(tx, rx, freqs, progress=progress or NullProgress(),
                                                    chunk_links=chunk_links, physics_only=with_physics_only)
    return (full, physics) if with_physics_only else full
