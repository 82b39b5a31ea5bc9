"""rf-fit's radio insets (rfir_stages.model.radio_insets; docs/physics.md 8.10): after the room's materials are
fitted, the parts of its large surfaces where the residuals gather become insets of their own material, placed
at the depth and started from the material that the held-out training links favour, fitted again, and kept only
where those links' MAE falls by more than MIN_GAIN_DB and two standard errors of the paired change.

rf_fit.room.radio_insets = "auto" (search; kept by that test) or "off".
"""
from __future__ import annotations

import copy
import string
from dataclasses import dataclass

import numpy as np
import torch

from rfir_core.text import plural
from rfir_stages.model.fit_physical import fit_materials, training_predictor
from rfir_stages.model.occlusion import FrozenGeometry
from rfir_stages.model.physical import MaterialParams
from rfir_stages.model.radio_insets import find_candidates, inset_surfels, shift_lengths
from rfir_stages.model.tabulated import DEFAULT_THICKNESS_M, TYPICAL_THICKNESS_M, tabulated_values

CHOICES = ("auto", "off")
# depths tried for an inset [m] along its surface's normal into the room: a board or a panel on a wall stands a
# few centimetres proud of it, the photos' plane a centimetre or two either side of the truth
OFFSETS_M = tuple(np.round(np.arange(-0.02, 0.0601, 0.01), 3))
# starting materials tried for an inset beside its surface's fitted one (ITU-R P.2040 and metal)
START_KEYS = ("metal", "glass", "wood", "plasterboard", "concrete")
MAX_SEARCH_LINKS = 10_000  # training links whose reflections are binned (evenly spaced; a cell needs many)
MIN_GAIN_DB = 0.05      # an inset set is kept when the held-out MAE falls by more than this and 2 standard errors


@dataclass
class RadioInsets:
    """What rf-fit continues with when insets are kept: the Gaussians' geometry and labels, the material of each
    Gaussian and the names, the room, its fit and check links, the fit (fit_physical.PhysicalFitResult), and a
    line per inset for the log."""

    geom: FrozenGeometry
    labels: np.ndarray
    label_names: list
    material: np.ndarray
    names: list
    room: object
    links: object
    check: tuple
    res: object
    lines: list


def _mae(links, target_db: np.ndarray, params) -> np.ndarray:
    """|measured - predicted| [M] dB of links with the materials params (no device gains)."""
    with torch.no_grad():
        return (training_predictor(links, torch.as_tensor(target_db))(params)
                - torch.as_tensor(target_db)).abs()[:, 0].numpy()


def _shifted(links, moved: np.ndarray, offset_m: float):
    """The links (RoomLinks, or BandLinks of several) with the paths off the patches `moved` [P] bool moved by
    offset_m (radio_insets.shift_lengths); their diffuse terms as they are."""
    if hasattr(links, "parts"):
        out = copy.copy(links)
        out.parts = [_shifted(p, moved, offset_m) for p in links.parts]
        return out
    out = copy.copy(links)
    out.paths = shift_lengths(links.paths, moved, offset_m)
    return out


def _extended(params: MaterialParams, source: list[int]) -> MaterialParams:
    """params with one more material per entry of source, each a copy of material source[k]'s values."""
    n = params.num + len(source)
    out = MaterialParams(n, sigma_exponent=params.sigma_exponent, shared_scattering=params.shared_scattering,
                         thickness_m=None if params.half_space else 0.05)
    idx = torch.as_tensor(list(range(params.num)) + list(source))
    with torch.no_grad():
        for name in ("t_eps", "t_sig", "t_s", "t_th"):
            getattr(out, name).copy_(getattr(params, name)[idx])
        out.gain_db.copy_(params.gain_db)
    return out


def _set_start(params: MaterialParams, index: int, key: str, freq_hz: float) -> None:
    eps_r, sigma = tabulated_values(key, freq_hz, params.sigma_exponent)
    params.set_values(index, eps_r=eps_r, sigma_1ghz=max(sigma, 1e-4),
                      thickness_m=TYPICAL_THICKNESS_M.get(key, DEFAULT_THICKNESS_M))


def search(*, scene_labels, label_names, geom: FrozenGeometry, room, material: np.ndarray, names: list, links, res,
           check, tx: np.ndarray, rx: np.ndarray, fit: np.ndarray, check_rows: np.ndarray, target_db: np.ndarray,
           residual_db: np.ndarray,
           freq_hz: float, band: str, axes, make_room, fit_cfg, progress, weights=None) -> RadioInsets | None:
    """Search, place, fit and test radio insets (module docstring); None when none is found or kept.

    scene_labels [G] int (-1: none), label_names: the scene's; material [G], names: rf-fit's materials; links /
    check: the fit's and the held-out training links (check = (links, target_db [C, 1])); tx, rx [M, 3] m the
    training links, fit [K] and check_rows [C] their rows in the fit and the check; target_db [M] dB and
    residual_db [M] dB (measured - predicted by the fit `res`) of every training link;
    make_room(geom, labels, material) -> RoomGeometry as rf-fit builds it."""
    if scene_labels is None or check is None:
        return None
    target = np.asarray(target_db, np.float64)
    rows = np.unique(np.linspace(0, len(tx) - 1, min(len(tx), MAX_SEARCH_LINKS)).round().astype(np.int64))
    means = geom.means.numpy()
    found = find_candidates(tx[rows], rx[rows], np.asarray(residual_db)[rows], room.patches, means)
    if not found:
        progress.log("radio insets: none (no part of a surface where the residuals gather; rf_fit.room.radio_insets)")
        return None
    labels = np.asarray(scene_labels, np.int64).copy()
    mat = np.asarray(material, np.int64).copy()
    lnames, mnames = [str(s) for s in label_names], list(names)
    moves, source = [], []
    for k, c in enumerate(found):
        idx = inset_surfels(c, room.patches, means, geom.normals.numpy())
        letter = string.ascii_lowercase[k]
        labels[idx] = len(lnames)
        lnames.append(f"radio_{letter}_00")
        source.append(int(room.material_of_patch[c.patch]))
        mat[idx] = len(mnames)
        mnames.append(f"radio_{letter}")
        moves.append((idx, c))
    progress.log(f"radio insets: {plural(len(found), 'candidate')} where the residuals gather ("
                 + "; ".join(f"{mnames[len(names) + k]}: {c.area_m2():.1f} m^2 of the {names[source[k]]} surface, "
                             f"{c.cells} cells" for k, c in enumerate(found))
                 + "); placing and fitting them (rf_fit.room.radio_insets)")
    # depth and starting material of each inset on the held-out links, the paths traced once and moved analytically
    room2 = make_room(geom, labels, mat)
    check2 = (room2.band_links(tx[check_rows], rx[check_rows], freq_hz, band, axes=axes.rows(check_rows)), check[1])
    params = _extended(res.params, source)
    offsets = []
    for k in range(len(moves)):
        m = len(names) + k
        moved = room2.material_of_patch == m
        best = (np.inf, 0.0, None)
        for offset in OFFSETS_M:
            shifted = _shifted(check2[0], moved, offset)
            for key in (None,) + START_KEYS:
                trial = _extended(params, [])
                if key is not None:
                    _set_start(trial, m, key, freq_hz)
                err = float(_mae(shifted, check2[1], trial).mean())
                if err < best[0]:
                    best = (err, float(offset), key)
        if best[2] is not None:
            _set_start(params, m, best[2], freq_hz)
        offsets.append(best[1])
    # the insets moved for real and traced again: the model predicts what it was fitted on
    new_means = geom.means.clone()
    for (idx, c), offset in zip(moves, offsets):
        new_means[idx] += torch.as_tensor(offset * c.toward, dtype=new_means.dtype)
    geom3 = FrozenGeometry(new_means, geom.log_scales, geom.rotations, geom.normals)
    room3 = make_room(geom3, labels, mat)
    links3 = room3.band_links(tx[fit], rx[fit], freq_hz, band, axes=axes.rows(fit))
    check3 = (room3.band_links(tx[check_rows], rx[check_rows], freq_hz, band, axes=axes.rows(check_rows)), check[1])
    res3 = fit_materials(links3, len(mnames), target[fit, None], fit_cfg, progress, label="physical room, radio insets",
                         initial=params, weights=weights)
    before, after = _mae(check[0], check[1], res.params), _mae(check3[0], check3[1], res3.params)
    gain, se = float(before.mean() - after.mean()), float((before - after).std() / np.sqrt(len(before)))
    lines = [f"{mnames[len(names) + k]}: {c.area_m2():.1f} m^2, moved {offsets[k] * 100:+.0f} cm into the room"
             for k, (_, c) in enumerate(moves)]
    verdict = (f"held-out MAE {before.mean():.3f} -> {after.mean():.3f} dB on "
               f"{plural(len(before), 'training link')} the fit did not use (standard error of the change {se:.3f})")
    if gain <= max(MIN_GAIN_DB, 2 * se):
        progress.log(f"radio insets: not kept ({verdict}; kept when it falls by more than {MIN_GAIN_DB:g} dB and 2 "
                     "standard errors)")
        return None
    progress.log(f"radio insets: kept ({verdict}): " + "; ".join(lines))
    return RadioInsets(geom3, labels, lnames, mat, mnames, room3, links3, check3, res3, lines)
