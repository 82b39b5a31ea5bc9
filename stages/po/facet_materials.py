"""Radio materials for the PO solver, as numpy wrappers of rfir_core.physics.materials.

The material laws (ITU-R P.2040), Fresnel and slab coefficients are defined once, in
rfir_core.physics.materials (docs/physics.md section 8); this module gives the PO solver numpy
arrays, material names per facet and the scalar-PO reflection of a facet.
"""
from __future__ import annotations

import numpy as np

from rfir_core.physics import materials as _m
from rfir_core.physics.materials import C0, EPS0, ITU_MATERIALS, PEC  # noqa: F401 - re-exported


def known_materials() -> list[str]:
    return sorted(ITU_MATERIALS) + [PEC]


def relative_permittivity(material: str, freq_hz, *, strict_range: bool = False) -> np.ndarray:
    """Complex relative permittivity eta = eps_r' - j sigma / (eps_0 2 pi f) of an ITU material.

    Outside the ITU validity range the power law is extrapolated (strict_range=True raises).
    "pec" returns an infinite imaginary part (use `fresnel` directly, it handles it).
    """
    f = np.asarray(freq_hz, dtype=float)
    key = _m.material_key(material)
    if key == PEC:
        return np.full(f.shape, complex(1.0, -np.inf))
    fmin, fmax = _m.itu_range_ghz(key)
    if strict_range and (np.any(f / 1e9 < fmin) or np.any(f / 1e9 > fmax)):
        raise ValueError(f"{material}: ITU-R P.2040 values hold for {fmin}-{fmax} GHz")
    eps_r, sigma = _m.itu_law(key, f)
    return np.asarray(_m.permittivity(eps_r, sigma, f).numpy()).reshape(f.shape)


def fresnel(eta, cos_theta, freq_hz=None, thickness_m=None) -> tuple[np.ndarray, np.ndarray]:
    """(R_TE, R_TM) of a half-space (thickness None/0) or a slab, broadcasting all arguments.

    eta: complex relative permittivity (np.inf imaginary part -> perfect conductor).
    cos_theta: cosine of the incidence angle (from the normal), clipped to [0, 1].
    """
    slab = thickness_m is not None and np.any(np.asarray(thickness_m) > 0)
    if slab and freq_hz is None:
        raise ValueError("a slab reflection coefficient needs freq_hz")
    k0 = 2.0 * np.pi * np.asarray(freq_hz, dtype=float) / C0 if slab else None
    r_te, r_tm = _m.fresnel(np.asarray(eta, dtype=complex), np.asarray(cos_theta, dtype=float), k0,
                            np.asarray(thickness_m, dtype=float) if slab else None)
    return r_te.numpy(), r_tm.numpy()


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
