"""Radio materials for the PO solver: ITU-R P.2040 permittivity/conductivity and Fresnel reflection.

Conventions (the same as PHYSICS.md and Sionna RT):
- complex relative permittivity `eta = eps_r' - j sigma / (eps_0 omega)` (time factor exp(+j omega t));
- `R_TE` (E perpendicular to the plane of incidence) and `R_TM` (E in the plane of incidence) as in
  ITU-R P.2040 section 2.2.2, with the TM reference direction `e_par = k_hat x e_perp` for both the
  incident and the reflected wave. With that convention a perfect conductor has `R_TE = -1` and
  `R_TM = +1`, and at normal incidence `R_TM = -R_TE`;
- a slab of thickness d (the way Sionna's `itu-radio-material` uses `thickness`) uses the ITU-R
  P.2040 multiple-reflection formula `R = R' (1 - e^{-j2q}) / (1 - R'^2 e^{-j2q})`,
  `q = (2 pi d / lambda) sqrt(eta - sin^2 theta)`; `thickness=None` gives the half-space value.
"""
from __future__ import annotations

import numpy as np

C0 = 299_792_458.0
EPS0 = 8.8541878128e-12

# ITU-R P.2040-3, Table 3 (the 1-100 GHz rows; frequency range in GHz): eps_r' = a f^b, sigma = c f^d
# [S/m], f in GHz. "plastic" is NOT an ITU material: rfir's stand-in for ABS (eps_r' ~ 2.7,
# tan delta ~ 0.005), added so a per-facet material array can name it.
ITU_MATERIALS: dict[str, tuple[float, float, float, float, float, float]] = {
    # name: (a, b, c, d, f_min_ghz, f_max_ghz)
    "vacuum": (1.0, 0.0, 0.0, 0.0, 0.001, 100.0),
    "concrete": (5.24, 0.0, 0.0462, 0.7822, 1.0, 100.0),
    "brick": (3.91, 0.0, 0.0238, 0.16, 1.0, 40.0),
    "plasterboard": (2.73, 0.0, 0.0085, 0.9395, 1.0, 100.0),
    "wood": (1.99, 0.0, 0.0047, 1.0718, 0.001, 100.0),
    "glass": (6.31, 0.0, 0.0036, 1.3394, 0.1, 100.0),
    "ceiling_board": (1.48, 0.0, 0.0011, 1.0750, 1.0, 100.0),
    "chipboard": (2.58, 0.0, 0.0217, 0.7800, 1.0, 100.0),
    "plywood": (2.71, 0.0, 0.33, 0.0, 1.0, 40.0),
    "marble": (7.074, 0.0, 0.0055, 0.9262, 1.0, 60.0),
    "floorboard": (3.66, 0.0, 0.0044, 1.3515, 50.0, 100.0),
    "metal": (1.0, 0.0, 1e7, 0.0, 1.0, 100.0),
    "very_dry_ground": (3.0, 0.0, 0.00015, 2.52, 1.0, 10.0),
    "medium_dry_ground": (15.0, -0.1, 0.035, 1.63, 1.0, 10.0),
    "wet_ground": (30.0, -0.4, 0.15, 1.30, 1.0, 10.0),
    "plastic": (2.7, 0.0, 0.00075, 1.0, 0.1, 100.0),  # rfir, not ITU (ABS-like)
}
PEC = "pec"  # ideal conductor: R_TE = -1, R_TM = +1 at every angle and frequency


def known_materials() -> list[str]:
    return sorted(ITU_MATERIALS) + [PEC]


def _key(name: str) -> str:
    key = str(name).strip().lower().replace("-", "_").replace(" ", "_")
    if key.startswith("itu_"):
        key = key[4:]
    if key not in ITU_MATERIALS and key != PEC:
        raise ValueError(f"unknown material {name!r} (known: {', '.join(known_materials())})")
    return key


def relative_permittivity(material: str, freq_hz, *, strict_range: bool = False) -> np.ndarray:
    """Complex relative permittivity eta = eps_r' - j sigma / (eps_0 2 pi f) of an ITU material.

    Outside the ITU validity range the power law is extrapolated (strict_range=True raises).
    "pec" returns an infinite imaginary part (use `fresnel` directly, it handles it).
    """
    f = np.asarray(freq_hz, dtype=float)
    key = _key(material)
    if key == PEC:
        return np.full(f.shape, complex(1.0, -np.inf))
    a, b, c, d, fmin, fmax = ITU_MATERIALS[key]
    fg = f / 1e9
    if strict_range and (np.any(fg < fmin) or np.any(fg > fmax)):
        raise ValueError(f"{material}: ITU-R P.2040 values hold for {fmin}-{fmax} GHz")
    eps_r = a * fg**b
    sigma = c * fg**d
    return eps_r - 1j * sigma / (EPS0 * 2.0 * np.pi * f)


def fresnel(eta, cos_theta, freq_hz=None, thickness_m=None) -> tuple[np.ndarray, np.ndarray]:
    """(R_TE, R_TM) of a half-space (thickness None/0) or a slab, broadcasting all arguments.

    eta: complex relative permittivity (np.inf imaginary part -> perfect conductor).
    cos_theta: cosine of the incidence angle (from the normal), clipped to [0, 1].
    """
    eta = np.asarray(eta, dtype=complex)
    c = np.clip(np.asarray(cos_theta, dtype=float), 0.0, 1.0)
    s2 = 1.0 - c * c
    pec = ~np.isfinite(eta)
    eta_f = np.where(pec, 4.0 + 0j, eta)  # placeholder for PEC entries, overwritten below
    root = np.sqrt(eta_f - s2)  # principal branch: Re > 0, Im <= 0 for lossy media (decaying wave)
    with np.errstate(divide="ignore", invalid="ignore"):  # vacuum at grazing: 0/0 -> -1 below
        r_te = (c - root) / (c + root)
        r_tm = (eta_f * c - root) / (eta_f * c + root)
    r_te = np.where(np.isfinite(r_te), r_te, -1.0)
    r_tm = np.where(np.isfinite(r_tm), r_tm, -1.0)
    if thickness_m is not None and np.any(np.asarray(thickness_m) > 0):
        if freq_hz is None:
            raise ValueError("a slab reflection coefficient needs freq_hz")
        k0 = 2.0 * np.pi * np.asarray(freq_hz, dtype=float) / C0
        q = k0 * np.asarray(thickness_m, dtype=float) * root
        # exp(-j 2 q) decays for lossy slabs; clip the exponent so huge losses give 0, not overflow
        ph = np.exp(np.maximum(np.real(-2j * q), -700.0) + 1j * np.imag(-2j * q))
        slab = np.asarray(thickness_m, dtype=float) > 0
        r_te = np.where(slab, r_te * (1.0 - ph) / (1.0 - r_te**2 * ph), r_te)
        r_tm = np.where(slab, r_tm * (1.0 - ph) / (1.0 - r_tm**2 * ph), r_tm)
    shape = np.broadcast(r_te, pec).shape
    r_te = np.where(pec, -1.0 + 0j, np.broadcast_to(r_te, shape))
    r_tm = np.where(pec, 1.0 + 0j, np.broadcast_to(r_tm, shape))
    return r_te, r_tm


def permittivity_array(material, freq_hz) -> np.ndarray:
    """relative_permittivity for one name or an array of names, broadcast against freq_hz."""
    names = np.asarray(material)
    f = np.asarray(freq_hz, dtype=float)
    if names.ndim == 0:
        return relative_permittivity(str(names), f)
    shape = np.broadcast_shapes(names.shape, f.shape)
    names_b = np.broadcast_to(names, shape)
    f_b = np.broadcast_to(f, shape)
    eta = np.empty(shape, dtype=complex)
    for u in np.unique(names_b):
        m = names_b == u
        eta[m] = relative_permittivity(str(u), f_b[m])
    return eta


def itu_reflection_coefficient(material, freq_hz, cos_theta=1.0, polarization: str = "TE",
                               thickness_m=None) -> np.ndarray:
    """Reflection coefficient of an ITU material (or "pec") at frequency f and incidence cos_theta.

    polarization "TE" (E perpendicular to the plane of incidence) or "TM". At normal incidence
    R_TE is the value to use as the scalar `face_reflection` of `po_scattered_field` (metal ->
    about -1): the scalar mode scales the perfect-conductor PO current by `-Gamma`.
    `material` may be one name or an array of names (broadcast against freq_hz / cos_theta).
    """
    eta = permittivity_array(material, freq_hz)
    r_te, r_tm = fresnel(eta, cos_theta, freq_hz, thickness_m)
    p = polarization.upper()
    if p not in ("TE", "TM"):
        raise ValueError("polarization must be 'TE' or 'TM'")
    return r_te if p == "TE" else r_tm


def face_reflection_from_materials(materials, thickness_m=None):
    """A callable freq_hz -> (F,) complex normal-incidence R_TE per facet (the scalar PO mode)."""
    names = np.asarray(materials)

    def gamma(freq_hz):
        return itu_reflection_coefficient(names, float(freq_hz), 1.0, "TE", thickness_m)

    return gamma
