"""Fitted materials that are not physical for their surface, named with alternatives and their error on links.

A room fit can end with a floor fitted as a metal, every wall at scattering S 1.0 or a wall 9 mm thick: values
that explain the training links but not what the surface is, and that mislead where the survey does not reach.
After the fit, each material whose name gives its surface class (floor, ceiling, wall, or a building material a
floor-plan wall is labelled by; a name that names metal is left alone) is checked against the thresholds below; each flagged material is then replaced in turn by two or
three tabulated materials of its class (ITU-R P.2040 at their typical thickness, its S kept) or, for an S at the
top of its range, by lower S, the other materials left as fitted, and every variant is scored by its mean
absolute dB error on the scoring links (links the fit did not use where there are any), the system gain refitted
for each variant as the median residual (the MAE's optimum; one number over all the links, alike for every
variant). Cost: (1 + alternatives) evaluations of the scoring links per flagged material.

An alternative replaces the fitted value only when the links scored are links the fit did not use and its error
there is no larger than the fitted value's (PREFER_MARGIN_DB of 0): those links then cannot prefer the unphysical
value, and the physical one carries to where they do not reach. On the links the values were fitted to, the check
names the alternatives and changes nothing: the fitted value's error there has the fit's optimism, and a tabulated
material that merely fits about as well is the tabulated step's decision (rfir_stages.model.tabulated, one standard
error), not this check's.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch

from rfir_core.physics.materials import ITU_MATERIALS

from .physical import MaterialParams
from .tabulated import TYPICAL_THICKNESS_M, named_material, tabulated_values

# sigma [S/m] at the fitted frequency above which a floor, ceiling or wall reads as a conductor: the wettest
# ITU-R P.2040 ground is a few S/m at GHz and every building material under 1 S/m, so 100 S/m is a metal-like fit
CONDUCTOR_SIGMA_S_PER_M = 100.0
# |Gamma(0)| above which a surface reflects as a metal: the tabulated building materials at their typical
# thicknesses reach about 0.70 at 2.4 GHz (glass; identifiability.WIDE_RANGE), a metal 1
METAL_GAMMA = 0.9
# scattering S at the top of its range [0, 1): a surface that sends almost nothing specularly, which a smooth floor
# or painted wall does not (measured S of building surfaces are about 0.2-0.6)
S_TOP = 0.95
# a wall slab thinner than this [m] is thinner than any partition built (plasterboard is 12.5 mm, on studs)
MIN_WALL_THICKNESS_M = 0.02
# an alternative replaces the fitted value when its MAE is at most the fitted value's plus this [dB] (module docstring)
PREFER_MARGIN_DB = 0.0
# the tabulated alternatives of each surface class (table keys, at TYPICAL_THICKNESS_M)
CLASS_ALTERNATIVES = {"floor": ("concrete", "wood", "floorboard"),
                      "ceiling": ("concrete", "ceiling_board", "plasterboard"),
                      "wall": ("concrete", "brick", "plasterboard")}
S_ALTERNATIVES = (0.5, 0.2)     # the lower S scored for an S at the top of its range


@dataclass
class MaterialFlag:
    """A flagged material: index, name, surface class, what is implausible (words), the variants scored
    {label: MAE dB} (the fitted value first, under "fitted"), the label taken ("" where the fit stays) and its
    table key ("" for an S)."""

    index: int
    name: str
    surface: str
    reason: str
    maes_db: dict = field(default_factory=dict)
    taken: str = ""
    taken_key: str = ""

    def words(self, links_words: str) -> str:
        """'floor: fitted metal-like (sigma 2.4e+07 S/m), MAE 3.10 dB; concrete 20.0 cm: 3.40 dB; ...'."""
        fitted, *alts = self.maes_db.items()
        out = (f"{self.name}: fitted {self.reason}, MAE on {links_words} {fitted[1]:.2f} dB; "
               + "; ".join(f"{k}: {v:.2f} dB" for k, v in alts))
        if self.taken:
            out += f"; taken: {self.taken} (no worse than the fitted value on those links)"
        return out


def surface_class(name: str) -> str | None:
    """"floor", "ceiling" or "wall" from a material's name (wall_a, partition, floor_1, ceiling_concrete), or None.
    A name that names a tabulated building material and no floor or ceiling is a wall ("concrete", "glass": rfir
    import floorplan labels each wall by its material)."""
    low = str(name).lower()
    for cls, pattern in (("floor", r"floor(?!board)"), ("ceiling", r"ceiling(?!_board)"),
                         ("wall", r"wall|partition")):
        if re.search(rf"(^|[^a-z]){pattern}", low):
            return cls
    named = named_material(name)
    if named is None or named == "metal" or named.endswith("_ground"):
        return None
    return {"floorboard": "floor", "ceiling_board": "ceiling"}.get(named, "wall")


def flag_reasons(row: dict, thickness_known: bool = True) -> list[str]:
    """What is implausible about one material_rows row (keys material, sigma_s_per_m, gamma_normal_abs,
    scattering, thickness_m) for its surface class; [] for a material of no class or named metal."""
    cls = surface_class(row["material"])
    if cls is None or named_material(row["material"]) == "metal":
        return []
    out = []
    if row["sigma_s_per_m"] > CONDUCTOR_SIGMA_S_PER_M or row["gamma_normal_abs"] > METAL_GAMMA:
        out.append(f"metal-like (sigma {row['sigma_s_per_m']:.3g} S/m, |Gamma(0)| {row['gamma_normal_abs']:.2f})")
    if row["scattering"] >= S_TOP:
        out.append(f"scattering S {row['scattering']:.2f} (top of its range)")
    # a material named by one that is thin itself (glass 1 cm, plasterboard 1.25 cm) may be as thin as that
    named = named_material(row["material"])
    thin_built = named is not None and TYPICAL_THICKNESS_M.get(named, MIN_WALL_THICKNESS_M) < MIN_WALL_THICKNESS_M
    if cls == "wall" and thickness_known and not thin_built and row["thickness_m"] < MIN_WALL_THICKNESS_M:
        out.append(f"{row['thickness_m'] * 100:.1f} cm thick")
    return out


def held_out_mae(predict_db: Callable[[MaterialParams], torch.Tensor], params: MaterialParams, target_db) -> float:
    """Mean |target - predicted| dB over the links of predict_db (-> [M, K] dB; target_db [M, K] dB), the system
    gain refitted as the median residual."""
    with torch.no_grad():
        res = np.asarray(target_db, np.float64).ravel() - predict_db(params).numpy().ravel()
    return float(np.abs(res - np.median(res)).mean())


def alternatives(surface: str, reason: str, freq_hz: float, sigma_exponent: float,
                 named: str | None = None) -> list[tuple[str, dict]]:
    """(label, MaterialParams.set_values keywords) of the variants scored for a flag: the class's tabulated
    materials valid at freq_hz [Hz] (in MaterialParams' law with sigma_exponent; the one the material's name
    names first, `named`, three in all) for a metal-like or thin fit, lower S for an S at the top of its range."""
    out = []
    if "metal-like" in reason or "thick" in reason:
        f_ghz = float(freq_hz) / 1e9
        keys = CLASS_ALTERNATIVES[surface]
        if named in TYPICAL_THICKNESS_M and named != "metal":
            keys = (named, *(k for k in keys if k != named))[:3]
        for key in keys:
            law = ITU_MATERIALS[key]
            if law[4] <= f_ghz <= law[5]:
                th = TYPICAL_THICKNESS_M[key]
                eps, sig = tabulated_values(key, freq_hz, sigma_exponent)
                out.append((f"{key.replace('_', ' ')} {th * 100:g} cm", {"key": key, "eps_r": eps, "sigma_1ghz": sig,
                                                                       "thickness_m": th}))
    if "scattering" in reason:
        out += [(f"S {s:g}", {"scattering": s}) for s in S_ALTERNATIVES]
    return out


def check_materials(predict_db: Callable[[MaterialParams], torch.Tensor], params: MaterialParams, target_db,
                    rows: list[dict], freq_hz: float, held_out: bool) -> list[MaterialFlag]:
    """Flag the materials of `params` (rows: material_rows of it, one per material) and score their alternatives
    on the links of predict_db(params) -> [M, K] dB against target_db [M, K] dB (module docstring). held_out: the
    links are links the fit did not use; then an alternative no worse than the fitted value by PREFER_MARGIN_DB is
    put into `params` in place (flag.taken, flag.taken_key: its table key, "" for an S)."""
    flags = []
    for i, row in enumerate(rows):
        reasons = flag_reasons(row, not params.half_space)
        if not reasons:
            continue
        flag = MaterialFlag(i, row["material"], surface_class(row["material"]), "; ".join(reasons))
        flag.maes_db["fitted"] = held_out_mae(predict_db, params, target_db)
        keep = {k: v.detach().clone() for k, v in params.state_dict().items()}
        best = None
        for label, kw in alternatives(flag.surface, flag.reason, freq_hz, params.sigma_exponent,
                                      named_material(row["material"])):
            params.set_values(i, **{k: v for k, v in kw.items() if k != "key"})
            flag.maes_db[label] = held_out_mae(predict_db, params, target_db)
            params.load_state_dict(keep)
            if best is None or flag.maes_db[label] < flag.maes_db[best[0]]:
                best = (label, kw)
        if held_out and best is not None and flag.maes_db[best[0]] <= flag.maes_db["fitted"] + PREFER_MARGIN_DB:
            params.set_values(i, **{k: v for k, v in best[1].items() if k != "key"})
            flag.taken, flag.taken_key = best[0], best[1].get("key", "")
        flags.append(flag)
    return flags

