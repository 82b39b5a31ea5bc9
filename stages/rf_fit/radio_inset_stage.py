"""rf-fit's radio insets and surface depths (rfir_stages.model.radio_insets; docs/physics.md 8.10): after the room's
materials are fitted, the parts of its large surfaces where the residuals gather become insets of their own
material, and every large surface (inset or not) is placed at the depth along its normal, and started from the
material, that best predict the fit's links; the moved geometry is traced again and fitted, and the result kept
only where the training links the fit did not use say so: their MAE falls by more than MIN_GAIN_DB and two
standard errors of the paired change.

rf_fit.room.radio_insets = "auto" (search; kept by that test) or "off".
"""
from __future__ import annotations

import copy
import string
import time
from dataclasses import dataclass

import numpy as np
import torch

from rfir_core.text import plural
from rfir_core.threads import single_thread_torch
from rfir_stages.model.fit_physical import fit_materials, training_predictor
from rfir_stages.model.occlusion import FrozenGeometry
from rfir_stages.model.physical import MaterialParams
from rfir_stages.model.radio_insets import (MIN_PATCH_AREA_M2, find_candidates, inset_surfels, shift_lengths,
                                           toward_side)
from rfir_stages.model.tabulated import DEFAULT_THICKNESS_M, TYPICAL_THICKNESS_M, set_tabulated

CHOICES = ("auto", "off")
# depths tried for a surface [m] along its normal into the room: a board or a panel on a wall stands a few
# centimetres proud of it, the photos' planes a few centimetres either side of the truth
OFFSETS_M = tuple(np.round(np.arange(-0.05, 0.0601, 0.01), 3))
# starting materials tried for a surface beside its fitted one (ITU-R P.2040 and metal)
START_KEYS = ("metal", "glass", "wood", "plasterboard", "concrete")
MAX_SEARCH_LINKS = 10_000  # training links whose reflections are binned (evenly spaced; a cell needs many)
MIN_GAIN_DB = 0.05       # the result is kept when the held-out MAE falls by more than this and 2 standard errors
MIN_MOVE_GAIN_DB = 0.02  # a surface is moved when that lowers the fitted links' MAE by more than this
MAX_SURFACES = 12        # the largest surfaces placed (each costs len(OFFSETS_M) + len(START_KEYS) evaluations)
ROUNDS = 2               # searches on the kept result's residuals (a part shows once a larger one is fitted)


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
    with torch.no_grad(), single_thread_torch():   # many small evaluations: thread hand-offs cost more than the work
        return (training_predictor(links, torch.as_tensor(target_db))(params)
                - torch.as_tensor(target_db)).abs()[:, 0].numpy()


def _shifted(links, offset_of_patch: np.ndarray):
    """The links (RoomLinks, or BandLinks of several) with their paths moved by offset_of_patch [P] m
    (radio_insets.shift_lengths); their diffuse terms as they are."""
    if hasattr(links, "parts"):
        out = copy.copy(links)
        out.parts = [_shifted(p, offset_of_patch) for p in links.parts]
        return out
    out = copy.copy(links)
    out.paths = shift_lengths(links.paths, offset_of_patch)
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
    """Material `index` of params set to tabulated material `key` at its typical thickness."""
    set_tabulated(params, index, key, freq_hz, TYPICAL_THICKNESS_M.get(key, DEFAULT_THICKNESS_M))


def _labelled(found: list, scene_labels, label_names, material: np.ndarray, names: list, room, means: np.ndarray,
              normals: np.ndarray) -> tuple[list, np.ndarray, np.ndarray, list, list, list]:
    """(the candidates kept, labels [G], material [G], label names, material names, source) with each candidate of
    found a label (`radio_a_00`, ...; lettered after an earlier round's) and a material (`radio_a`, ...) of its own
    after the scene's and rf-fit's, on its surfels (radio_insets.inset_surfels, patch indices of room) that no
    earlier candidate holds; one left without surfels is not kept (a material no patch has would leave the room's
    links a material short). source[k]: the material of kept candidate k's surface, whose values it starts from."""
    labels = np.asarray(scene_labels, np.int64).copy()
    mat = np.asarray(material, np.int64).copy()
    lnames, mnames = [str(s) for s in label_names], list(names)
    kept, source = [], []
    taken = np.zeros(len(mat), bool)
    earlier = sum(n.startswith("radio_") for n in mnames)       # an earlier round's insets keep their letters
    for c in found:
        idx = inset_surfels(c, room.patches, means, normals)
        idx = idx[~taken[idx]]
        if len(idx) == 0:
            continue
        taken[idx] = True
        letter = string.ascii_lowercase[(earlier + len(kept)) % 26]
        labels[idx] = len(lnames)
        lnames.append(f"radio_{letter}_00")
        source.append(int(room.material_of_patch[c.patch]))
        mat[idx] = len(mnames)
        mnames.append(f"radio_{letter}")
        kept.append(c)
    return kept, labels, mat, lnames, mnames, source


@dataclass
class _Move:
    """A surface searched: its surfels [n], its patches in the searched room [k], the unit normal into the room, its
    material, the offset [m] and starting material key (None: its fitted values) chosen, its name for the log, and
    the fitted links' MAE before and after its search."""
    surfels: np.ndarray
    patches: np.ndarray
    toward: np.ndarray
    material: int
    name: str
    offset: float = 0.0
    key: str | None = None
    as_surface: float = 0.0    # the fitted links' MAE [dB] with it as the surface around it (before its search)
    err: float = 0.0           # and with its chosen offset and start


def _searched_room(found, labels, mat, mnames, source, num_fitted, room, links, res, geom, tx, rx, fit, target_fit,
                   freq_hz, band, axes, make_room):
    """(room, its fitted links, the materials' parameters, a _Move per inset, the patches' offsets [P] m, all 0) with
    the insets of found (labelled by _labelled: labels, mat, mnames, source), each started from its surface's values;
    num_fitted: the first fit's material count; target_fit [K, 1] dB the fitted links' measurements."""
    room2 = make_room(geom, labels, mat) if found else room
    links2 = room2.band_links(tx[fit], rx[fit], freq_hz, band, axes=axes.rows(fit)) if found else links
    params = _extended(res.params, source)
    moves = [_Move(np.flatnonzero(mat == m), np.flatnonzero(room2.material_of_patch == m), found[k].toward, m, mnames[m])
             for k, m in enumerate(range(num_fitted, num_fitted + len(found)))]
    for _ in range(2):     # the second evaluation builds the diffuse terms' matrix, which the moved copies share
        _mae(links2, target_fit, params)
    return room2, links2, params, moves, np.zeros(room2.patches.num)


def _place(mv: _Move, inset: bool, links, offsets: np.ndarray, params: MaterialParams, target_fit: np.ndarray,
           freq_hz: float) -> None:
    """Surface mv given the starting material, then the depth, that best predict the fitted links (links, target_fit
    [K, 1] dB), with the other surfaces at offsets [P] m and materials params (both updated with its choice): its
    starting material first, where it is (a move must not stand in for a material the fit missed), then its depth
    with that material (an inset's with every starting material: a board's depth shows only once it is metal), moved
    only where that beats staying by MIN_MOVE_GAIN_DB."""
    here = _shifted(links, offsets)
    stay = (float(_mae(here, target_fit, params).mean()), 0.0, None)
    mv.as_surface = stay[0]
    for key in START_KEYS:
        trial = _extended(params, [])
        _set_start(trial, mv.material, key, freq_hz)
        err = float(_mae(here, target_fit, trial).mean())
        if err < stay[0] - 1e-9:
            stay = (err, 0.0, key)
    best = stay
    for offset in OFFSETS_M:
        if offset == 0.0:
            continue
        trial_offsets = offsets.copy()
        trial_offsets[mv.patches] = offset
        shifted = _shifted(links, trial_offsets)
        for key in ((None,) + START_KEYS if inset else (stay[2],)):
            trial = _extended(params, [])
            if key is not None:
                _set_start(trial, mv.material, key, freq_hz)
            err = float(_mae(shifted, target_fit, trial).mean())
            if err < best[0] - 1e-9:
                best = (err, float(offset), key)
    if best[0] > stay[0] - MIN_MOVE_GAIN_DB:
        best = stay
    mv.offset, mv.key, mv.err = best[1], best[2], best[0]
    offsets[mv.patches] = mv.offset
    if mv.key is not None:
        _set_start(params, mv.material, mv.key, freq_hz)


def search(*, scene_labels, label_names, geom: FrozenGeometry, room, material: np.ndarray, names: list, links, res,
           check, tx: np.ndarray, rx: np.ndarray, fit: np.ndarray, check_rows: np.ndarray, target_db: np.ndarray,
           residual_db: np.ndarray, freq_hz: float, band: str, axes, make_room, fit_cfg, progress,
           weights=None) -> RadioInsets | None:
    """Search, place, fit and test radio insets and surface depths (module docstring); None when nothing is kept.

    scene_labels [G] int (-1: none), label_names: the scene's; material [G], names: rf-fit's materials; links /
    check: the fit's and the held-out training links (check = (links, target_db [C, 1])); tx, rx [M, 3] m the
    training links, fit [K] and check_rows [C] their rows in the fit and the check; target_db [M] dB and
    residual_db [M] dB (measured - predicted by the fit `res`) of every training link;
    make_room(geom, labels, material) -> RoomGeometry as rf-fit builds it."""
    if scene_labels is None or check is None:
        return None
    target = np.asarray(target_db, np.float64)
    rows = np.unique(np.linspace(0, len(tx) - 1, min(len(tx), MAX_SEARCH_LINKS)).round().astype(np.int64))
    means, normals = geom.means.numpy(), geom.normals.numpy()
    found = find_candidates(tx[rows], rx[rows], np.asarray(residual_db)[rows], room.patches, means)
    found, labels, mat, lnames, mnames, source = _labelled(found, scene_labels, label_names, material, names, room,
                                                           means, normals)
    if found:
        progress.log(f"radio insets: {plural(len(found), 'candidate')} where the residuals gather ("
                     + "; ".join(f"{mnames[len(names) + k]}: {c.area_m2():.1f} m^2 of the {names[source[k]]} surface, "
                                 f"{c.cells} cells" for k, c in enumerate(found)) + ")")
    target_fit = target[fit, None]
    t0 = time.time()
    room2, links2, params, moves, offsets = _searched_room(found, labels, mat, mnames, source, len(names), room, links,
                                                           res, geom, tx, rx, fit, target_fit, freq_hz, band, axes,
                                                           make_room)
    for mv in moves:
        _place(mv, True, links2, offsets, params, target_fit, freq_hz)
    # an inset that no starting material or depth makes predict the fitted links better than its surface's fitted
    # material there (a group of cells high by chance) is dropped: its surfels return to their surface
    kept = [k for k, mv in enumerate(moves) if mv.err < mv.as_surface - MIN_MOVE_GAIN_DB]
    dropped = [mv.name for k, mv in enumerate(moves) if k not in kept]
    if dropped:
        progress.log(f"radio insets: {', '.join(dropped)} dropped: no starting material or depth beats its surface's "
                     f"fitted material there by {MIN_MOVE_GAIN_DB:g} dB on the fitted links"
                     + (" (the others lettered anew)" if len(dropped) < len(moves) else ""))
        found = [found[k] for k in kept]
        found, labels, mat, lnames, mnames, source = _labelled(found, scene_labels, label_names, material, names,
                                                               room, means, normals)
        placed = [moves[k] for k in kept]
        room2 = links2 = None      # freed before the next room is built: rooms of photo geometry take a gigabyte
        room2, links2, params, moves, offsets = _searched_room(found, labels, mat, mnames, source, len(names), room,
                                                               links, res, geom, tx, rx, fit, target_fit, freq_hz, band,
                                                               axes, make_room)
        for mv, was in zip(moves, placed):
            mv.offset, mv.key, mv.as_surface, mv.err = was.offset, was.key, was.as_surface, was.err
            offsets[mv.patches] = mv.offset
            if mv.key is not None:
                _set_start(params, mv.material, mv.key, freq_hz)
    # then the MAX_SURFACES largest other patches of MIN_PATCH_AREA_M2 or more
    big = [q for q in np.argsort(-room2.patches.area) if room2.patches.area[q] >= MIN_PATCH_AREA_M2
           and room2.material_of_patch[q] < len(names)][:MAX_SURFACES]
    for q in big:
        q = int(q)
        moves.append(_Move(np.flatnonzero(room2.patches.surfel_patch == q), np.array([q]),
                           toward_side(room2.patches.normal[q], room2.patches.point[q], tx[fit]),
                           int(room2.material_of_patch[q]),
                           lnames[int(room2.patches.label[q])] if room2.patches.label[q] >= 0 else f"patch {q}"))
        _place(moves[-1], False, links2, offsets, params, target_fit, freq_hz)
    changed = [mv for mv in moves if mv.offset != 0.0 or mv.key is not None]
    progress.log(f"radio insets and surface depths: {len(moves)} surfaces placed on the {len(fit)} fitted links in "
                 f"{time.time() - t0:.1f} s ("
                 + ("; ".join(f"{mv.name} {mv.offset * 100:+.0f} cm" + (f", from {mv.key}" if mv.key else "")
                              for mv in changed) if changed else "none moved") + ")")
    if not found and not changed:
        progress.log("radio insets: none, and no surface moved (rf_fit.room.radio_insets)")
        return None
    # the surfaces moved for real and traced again: the model predicts what it was fitted on
    new_means = geom.means.clone()
    for mv in moves:
        if mv.offset != 0.0:
            new_means[mv.surfels] += torch.as_tensor(mv.offset * mv.toward, dtype=new_means.dtype)
    geom3 = FrozenGeometry(new_means, geom.log_scales, geom.rotations, geom.normals)
    room2 = links2 = None
    room3 = make_room(geom3, labels, mat)
    links3 = room3.band_links(tx[fit], rx[fit], freq_hz, band, axes=axes.rows(fit))
    check3 = (room3.band_links(tx[check_rows], rx[check_rows], freq_hz, band, axes=axes.rows(check_rows)), check[1])
    res3 = fit_materials(links3, len(mnames), target_fit, fit_cfg, progress, label="physical room, moved surfaces",
                         initial=params, weights=weights)
    before, after = _mae(check[0], check[1], res.params), _mae(check3[0], check3[1], res3.params)
    gain, se = float(before.mean() - after.mean()), float((before - after).std() / np.sqrt(len(before)))
    verdict = (f"held-out MAE {before.mean():.3f} -> {after.mean():.3f} dB on "
               f"{plural(len(before), 'training link')} the fit did not use (standard error of the change {se:.3f})")
    if gain <= max(MIN_GAIN_DB, 2 * se):
        progress.log(f"radio insets and surface depths: not kept ({verdict}; kept when it falls by more than "
                     f"{MIN_GAIN_DB:g} dB and 2 standard errors)")
        return None
    # one fit as rf-fit reports and stores it: from the first fit's start, its loss curve through both, in the time of both
    res3.loss_curve = np.concatenate([res.loss_curve, res3.loss_curve])
    res3.initial_mae_db, res3.wall_time_s = res.initial_mae_db, res.wall_time_s + res3.wall_time_s
    res3.steps += res.steps
    res3.start = res.start
    lines = [f"{mv.name}: moved {mv.offset * 100:+.0f} cm into the room" + (f", started from {mv.key}" if mv.key else "")
             + (f" (a radio inset, {found[k].area_m2():.1f} m^2)" if k < len(found) else "")
             for k, mv in enumerate(moves) if k < len(found) or mv.offset != 0.0 or mv.key is not None]
    progress.log(f"radio insets and surface depths: kept ({verdict})")
    return RadioInsets(geom3, labels, lnames, mat, mnames, room3, links3, check3, res3, lines)
