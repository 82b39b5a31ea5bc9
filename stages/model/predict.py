"""Path gain predicted by a physical model (an `rf` artifact written by rf-fit with model = physical).

Any frequency: the material laws carry eps_r and sigma to it and the phases follow k. Frequencies
outside 0.1-100 GHz (where ITU-R P.2040 laws are given) are predicted with a printed warning.
Predicted power below FLOOR_DB (links that see no lit surfel: a plate edge-on) is reported at
FLOOR_DB, never as -inf or -3000 dB, and counted in the log. Many frequencies (a band) are
evaluated in frequency chunks, each link traced once; above band.EXACT_MAX_FREQS of them with the
fit's aggregated form (band.py). The artifact's residual
(residual.py) is applied on top: the gaussian form inside the field sum, the smooth form in dB (zero
at frequencies that were not fitted, said in the log), the smooth and blend forms in dB.
"""
from __future__ import annotations

import numpy as np
import torch

from rfir_core.progress import NullProgress
from .antenna_patterns import antenna_from_attrs
from .links import geometry_from_artifact, make_links, scene_centre
from .occlusion import make_provider

from .artifact import load_physical
from .band import EXACT_MAX_FREQS, band_field, band_power
from .physical import build_pairs
from .residual import kernel_form_at
from .sampling import cell_size_m, coarse_surfels_warning
from .second_order import planar_patches

FLOOR_DB = -250.0
VALID_GHZ = (0.1, 100.0)


def predict_physical_db(rf, tx, rx, freqs, task: str, *, occlusion: str = "auto", chunk_links: int = 64,
                        progress=None, with_physics_only: bool = False):
    """Path gain [L, K] dB for links tx/rx [L, 3] m at freqs [K] Hz; with_physics_only: (that, the
    physical model's alone, without the residual)."""
    progress = progress or NullProgress()
    model = load_physical(rf)
    ant = antenna_from_attrs(rf.free.get("model@attrs", {}))
    freqs = np.asarray(freqs, np.float64)
    outside = freqs[(freqs / 1e9 < VALID_GHZ[0]) | (freqs / 1e9 > VALID_GHZ[1])]
    if outside.size:
        progress.log(f"warning: {', '.join(f'{f / 1e9:g}' for f in outside)} GHz lies outside the range of the "
                     f"material laws ({VALID_GHZ[0]:g}-{VALID_GHZ[1]:g} GHz); predicted by extrapolating them")
    fitted = np.asarray(rf["rf/freq_hz"], np.float64)
    unfitted = [f for f in freqs if not np.any(np.abs(fitted - f) <= 1e-6 * f)]
    if unfitted and fitted.size == 1 and len(model.names) > 1:
        progress.log(f"predict: {len(model.names)} materials fitted at {fitted[0] / 1e9:g} GHz alone, predicted at "
                     f"{', '.join(f'{f / 1e9:g}' for f in unfitted[:4])} GHz: materials per label fitted at one "
                     "frequency carry over less well than one for the object (docs/rf-model.md, unseen frequency)")
    geom = geometry_from_artifact(rf)
    coarse = coarse_surfels_warning(cell_size_m(geom.log_scales, geom.rotations, geom.normals, model.areas_m2), freqs)
    if coarse:
        progress.log(f"warning: {coarse}")
    centre = scene_centre(geom)
    provider = make_provider(occlusion, geom) if model.settings.visibility else None
    labels = rf.get("gaussians/labels")
    patches = planar_patches(geom, model.areas_m2, None if labels is None else torch.as_tensor(np.asarray(labels)),
                             model.settings.min_patch_area_m2) \
        if model.settings.second_order or model.settings.edge_waves else None
    if model.settings.edge_waves:
        progress.log("predict: with the edge waves of the planar patches' outer edges (chosen at rf-fit; "
                     "docs/physics.md section 8.13)")
    res = model.residual
    surfel = res.params["surfel"] if res.form == "gaussian" else None
    gain = 10 ** (model.gain_db / 10)
    out = np.zeros((len(tx), len(freqs)))
    phys = np.zeros_like(out) if surfel is not None and with_physics_only else out
    if surfel is None and len(freqs) > EXACT_MAX_FREQS:
        progress.log(f"predict: {len(freqs)} frequencies: the fit's aggregated form (reflection coefficients on "
                     "2-degree angle nodes; band.py)")
    with progress.task("predict (physical)", total=len(tx)) as bar, torch.no_grad():
        for a in range(0, len(tx), chunk_links):
            links = make_links(tx[a:a + chunk_links], rx[a:a + chunk_links], freqs, centre, task)
            pairs = build_pairs(geom, links, ant, ant, provider, model.settings, model.areas_m2, patches)
            for dest, factor in ((out, surfel), (phys, None)) if phys is not out else ((out, surfel),):
                if factor is None and len(freqs) > EXACT_MAX_FREQS:   # a band: the fit's aggregated form
                    power = band_power(pairs, model.material_of_gaussian, model.mats)
                else:
                    field, diffuse = band_field(pairs, model.material_of_gaussian, model.mats, surfel_factor=factor)
                    power = field.abs() ** 2 + diffuse
                dest[a:a + chunk_links] = 10 * np.log10((power * gain).numpy() + 1e-300)
            bar.advance(links.num)
    low = out < FLOOR_DB
    if low.any():
        progress.log(f"predict: {int(low.sum())} of {low.size} predicted path gains are below {FLOOR_DB:g} dB "
                     "(no lit surfel seen); reported at that floor")
    out, phys = np.maximum(out, FLOOR_DB), np.maximum(phys, FLOOR_DB)
    if res.form in ("smooth", "blend"):
        out, missing = kernel_form_at(res, np.asarray(tx, float), np.asarray(rx, float), centre.numpy(), phys, freqs,
                                      np.asarray(rf["rf/freq_hz"], np.float64))
        if missing:
            progress.log(f"predict: {', '.join(f'{f / 1e9:g}' for f in missing)} GHz was not fitted: the physical "
                         "model alone there (the residual is zero at frequencies it was not fitted at)")
        out = np.maximum(out, FLOOR_DB)
    if res.form != "off":
        progress.log(f"predict: residual {res.form} ({res.chosen}) applied on top of the physical model")
    return (out, phys) if with_physics_only else out
