"""Fitted materials the training links cannot tell from a tabulated one (ITU-R P.2040), taken as it.

A room's links often determine a material's reflection and transmission at the angles they see and little
else: a thin lossy slab and 20 cm of concrete reflect alike off a wall no link crosses, and the fit ends in
whichever its start led to. After the fit, each material in turn is replaced by every tabulated building
material (materials.ITU_MATERIALS valid at the fitted frequency, metal included; the grounds only for a
material whose name names one) at the fitted slab thickness and at the material's typical thickness
(TYPICAL_THICKNESS_M), its scattering S kept, and its SHORTLIST best candidates are kept (a name that names a
tabulated material, "glass_partition", keeps that one alone where it is compatible). Then, in rounds, one
replacement at a time: every remaining material's shortlist is scored against the current state, and the
candidate of smallest increase of the training links' mean squared dB error is taken among those whose
increase is within `margin` standard errors (identifiability.block_standard_error: the one-standard-error
rule, a difference the links cannot resolve), both against the state before it and against the lowest error
reached so far (so replacements taken in turn cannot drift further than one such margin); the rounds end when
none is. A replacement may lower the error too: the starts of the fit can leave a material in a poorer optimum
than a tabulated one (docs/physics.md section 8.12). Cost: materials x candidates evaluations of the
training links, then about materials^2 x SHORTLIST / 2.

The links are rf-fit's training links the fit did not use where it fitted a subset (rf_fit.room.fit_links;
rf_fit.room_stage._check_links): on the links the values were fitted to, every alternative looks worse than it
is by the fit's optimism, so a tabulated material the data agree with could be refused there.

The materials stay what they were where the links tell them apart from every tabulated one; a
measured room of unlisted materials loses nothing the links can see.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from rfir_core.threads import single_thread_torch

from .identifiability import block_standard_error
from rfir_core.physics.materials import ITU_MATERIALS, METAL_SIGMA_S_PER_M, itu_law, power_law
from .physical import MaterialParams

# typical slab thickness [m] of each tabulated material (a name's starting value and a candidate's thickness)
TYPICAL_THICKNESS_M = {"glass": 0.01, "metal": 0.002, "concrete": 0.2, "brick": 0.15, "wood": 0.03,
                       "plasterboard": 0.0125, "ceiling_board": 0.015, "chipboard": 0.02, "plywood": 0.015,
                       "marble": 0.03, "floorboard": 0.02}
DEFAULT_THICKNESS_M = 0.05
SHORTLIST = 2               # candidates per material scored again in each round (the best against the fit)


@dataclass
class TabulatedChoice:
    """A material replaced by a tabulated one: material index, table key, slab thickness [m], and the increase of
    the training links' mean squared dB error over the state before it, in standard errors of that increase
    (negative: lower)."""

    index: int
    key: str
    thickness_m: float
    increase_se: float


def named_material(name: str) -> str | None:
    """The tabulated material a material's name names ("glass_partition" -> "glass"), or None."""
    low = str(name).lower()
    for key in sorted(ITU_MATERIALS, key=len, reverse=True):     # "ceiling_board" before shorter keys
        if key != "vacuum" and re.search(rf"(^|[^a-z]){key}([^a-z]|$)", low):
            return key
    return None


def set_tabulated(params, index: int, key: str, freq_hz: float, thickness_m: float) -> None:
    """Set material `index` of params (physical.MaterialParams) to tabulated material `key` at freq_hz [Hz],
    thickness_m [m] thick (tabulated_values)."""
    eps, sig = tabulated_values(key, freq_hz, params.sigma_exponent)
    params.set_values(index, eps_r=eps, sigma_1ghz=sig, thickness_m=thickness_m)


def tabulated_values(key: str, freq_hz: float, sigma_exponent: float) -> tuple[float, float]:
    """(eps_r, sigma at 1 GHz [S/m]) of tabulated material `key` in MaterialParams' law sigma_1GHz (f / 1 GHz)^
    sigma_exponent, equal to the table's law at freq_hz [Hz]."""
    if key == "metal":
        return 1.0, METAL_SIGMA_S_PER_M
    eps_r, sigma = itu_law(key, float(freq_hz))
    return float(eps_r), float(sigma) / power_law(1.0, sigma_exponent, float(freq_hz))


def candidates(freq_hz: float, fitted_thickness_m: float, named: str | None = None) -> list[tuple[str, float]]:
    """(table key, slab thickness [m]) of every tabulated building material valid at freq_hz [Hz] (the grounds only
    when `named`): at the fitted thickness and at its typical one (a metal at the fitted thickness alone: it
    passes nothing at any)."""
    f_ghz = float(freq_hz) / 1e9
    out = []
    for key, law in ITU_MATERIALS.items():
        if key == "vacuum" or not law[4] <= f_ghz <= law[5] or (key.endswith("_ground") and key != named):
            continue
        thick = {float(fitted_thickness_m)} if key == "metal" else \
            {float(fitted_thickness_m), TYPICAL_THICKNESS_M.get(key, DEFAULT_THICKNESS_M)}
        out += [(key, th) for th in sorted(thick)]
    return out


def take_tabulated(predict_db: Callable[[MaterialParams], torch.Tensor], params: MaterialParams, target_db,
                   freq_hz: float, names: list[str], margin: float = 1.0) -> list[TabulatedChoice]:
    """Replace the materials of `params` (in place) that the training links cannot tell from a tabulated one
    (module docstring). predict_db(params) -> [M, K] dB predicted path gain of the training links (the fit's own
    prediction); target_db [M, K] dB; freq_hz: the frequency [Hz] the table is read at; names [N]: the
    materials' names. Slab materials only (half-space fits are left as they are). Returns the replacements
    in the order taken."""
    if params.half_space:
        return []
    target = torch.as_tensor(np.asarray(target_db, dtype=np.float64))

    def per_link() -> torch.Tensor:          # [M] squared dB error per link, averaged over frequencies
        return ((predict_db(params) - target) ** 2).reshape(len(target), -1).mean(1)

    def score(d: torch.Tensor) -> float:     # the mean increase in standard errors (a decrease: below 0)
        return float(d.mean()) / max(block_standard_error(d), 1e-300)

    def put(i: int, key: str, th: float) -> None:
        set_tabulated(params, i, key, freq_hz, th)

    # many evaluations of small tensor ops: on a shared CPU thread hand-offs cost more than they save (as the fit)
    with torch.no_grad(), single_thread_torch():
        fitted_th = params.values().thickness_m.numpy().copy()
        base = per_link()
        shortlist = {}            # material -> its SHORTLIST best (score, key, thickness, errors) against the fit
        for i in range(params.num):
            keep = {k: v.detach().clone() for k, v in params.state_dict().items()}
            named = named_material(names[i]) if i < len(names) else None
            tried = []
            for key, th in candidates(freq_hz, fitted_th[i], named):
                put(i, key, th)
                err = per_link()
                tried.append((score(err - base), key, th, err))
                params.load_state_dict(keep)
            tried.sort(key=lambda t: t[0])
            own = [t for t in tried if t[1] == named and t[0] <= margin]
            shortlist[i] = own[:1] or tried[:SHORTLIST]
        # best first, every remaining shortlist scored again against the current state in each round: a replacement
        # taken changes the others' increases (20 cm of concrete on the floor makes it on the windows' wall too)
        taken: list[TabulatedChoice] = []
        current, lowest = base, base
        while shortlist:
            trials = []
            for i, cands in shortlist.items():
                keep = {k: v.detach().clone() for k, v in params.state_dict().items()}
                for first, key, th, err in cands:
                    if taken:                             # the first round is the first pass's state
                        put(i, key, th)
                        err = per_link()
                        params.load_state_dict(keep)
                    trials.append((score(err - current) if taken else first, i, key, th, err))
            trials.sort(key=lambda t: t[0])
            ok = [t for t in trials if t[0] <= margin
                  and float((t[4] - lowest).mean()) <= margin * block_standard_error(t[4] - lowest)]
            if not ok:
                break                                    # none left within the margin
            now, i, key, th, err = ok[0]
            put(i, key, th)
            taken.append(TabulatedChoice(int(i), key, float(th), now))
            del shortlist[i]
            current = err
            if float(err.mean()) < float(lowest.mean()):
                lowest = err
    return taken
