"""Radio materials: ITU-R P.2040 laws, Fresnel reflection, slab reflection and transmission.

The one definition of each term in rfir (docs/physics.md section 8); the physical-optics simulator
(rfir_stages.po.facet_materials) and the fitted physical model (rfir_stages.model.physical) both call it.

Conventions (those of Sionna RT and ITU-R P.2040):
- time factor exp(+j omega t); complex relative permittivity `eta = eps_r - j sigma / (eps_0 omega)`;
- material law, f in GHz: `eps_r = a f^b`, `sigma = c f^d` [S/m];
- `R_TE` (E perpendicular to the plane of incidence), `R_TM` (E in it) with the TM reference
  direction `k_hat x e_perp` for incident and reflected wave alike: a perfect conductor gives
  R_TE = -1, R_TM = +1, and at normal incidence R_TM = -R_TE;
- half-space, `r = sqrt(eta - sin^2 theta)`: `R_TE = (cos - r) / (cos + r)`,
  `R_TM = (eta cos - r) / (eta cos + r)`;
- slab of thickness d, `q = k0 d r` (multiple internal reflections):
  `R = G (1 - e^{-j2q}) / (1 - G^2 e^{-j2q})`, `T = (1 - G^2) e^{-jq} / (1 - G^2 e^{-j2q})`,
  G the half-space coefficient of the same polarisation. T is referred to the slab's faces (no
  extra free-space phase for the thickness).

Every function takes torch tensors or numpy arrays / floats and returns torch complex128 tensors
(differentiable in eta and thickness); `.numpy()` gives arrays back.
"""
from __future__ import annotations

import math

import numpy as np
import torch

from rfir_core.physics.closed_forms import C0  # noqa: F401 - the speed of light of every k0 = 2 pi f / C0


EPS0 = 8.8541878128e-12
# The one conductivity of a metal in rfir [S/m]: ITU-R P.2040-3 Table 3's "metal" row (c = 1e7, d = 0), the value
# Sionna RT's itu_metal gives the simulated data sets, so the fitter's metal is the simulator's.
METAL_SIGMA_S_PER_M = 1e7

# ITU-R P.2040-3, Table 3 (the 1-100 GHz rows; validity range in GHz): eps_r = a f^b, sigma = c f^d
# [S/m], f in GHz. "plastic" is NOT an ITU material: rfir's stand-in for ABS (eps_r ~ 2.7,
# tan delta ~ 0.005), so a scene can name it.
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
    "metal": (1.0, 0.0, METAL_SIGMA_S_PER_M, 0.0, 1.0, 100.0),
    "very_dry_ground": (3.0, 0.0, 0.00015, 2.52, 1.0, 10.0),
    "medium_dry_ground": (15.0, -0.1, 0.035, 1.63, 1.0, 10.0),
    "wet_ground": (30.0, -0.4, 0.15, 1.30, 1.0, 10.0),
    "plastic": (2.7, 0.0, 0.00075, 1.0, 0.1, 100.0),  # rfir, not ITU (ABS-like)
}
PEC = "pec"  # ideal conductor: R_TE = -1, R_TM = +1 at every angle and frequency


def _c128(x) -> torch.Tensor:
    """complex128 tensor (Python and numpy numbers converted directly: no float32 detour)."""
    return x.to(torch.complex128) if torch.is_tensor(x) else torch.as_tensor(np.asarray(x, dtype=np.complex128))


def _f64(x) -> torch.Tensor:
    return x.to(torch.float64) if torch.is_tensor(x) else torch.as_tensor(np.asarray(x, dtype=np.float64))


def material_key(name: str) -> str:
    """Canonical table key of a material name ("ITU Concrete" -> "concrete"); ValueError if unknown."""
    key = str(name).strip().lower().replace("-", "_").replace(" ", "_")
    if key.startswith("itu_"):
        key = key[4:]
    if key not in ITU_MATERIALS and key != PEC:
        known = sorted(ITU_MATERIALS) + [PEC]
        raise ValueError(f"unknown material {name!r} (known: {', '.join(known)})")
    return key


def abs2(z: torch.Tensor) -> torch.Tensor:
    """|z|^2 of a complex tensor as re^2 + im^2, with a finite gradient everywhere: abs() has none at 0,
    and returns NaN for a coefficient that has underflowed (a metal slab's transmission)."""
    return z.real ** 2 + z.imag ** 2


def permittivity(eps_r, sigma_s_per_m, freq_hz) -> torch.Tensor:
    """Complex relative permittivity eta = eps_r - j sigma / (eps_0 2 pi f), broadcast; complex128."""
    omega = 2.0 * math.pi * _f64(freq_hz)
    return _c128(eps_r) - 1j * _c128(_f64(sigma_s_per_m) / (EPS0 * omega))


def power_law(value_1ghz, exponent, freq_hz):
    """The ITU-R P.2040 frequency law of a material parameter: value_1ghz (f / 1 GHz)^exponent.

    eps_r = a f^b and sigma = c f^d [S/m] (f in GHz) are this law with (a, b) and (c, d). Broadcasts numpy
    arrays, floats and torch tensors alike (the result has the arguments' type)."""
    return value_1ghz * (freq_hz / 1e9) ** exponent


def law_permittivity(eps_r_1ghz, eps_r_exponent, sigma_1ghz, sigma_exponent, freq_hz) -> torch.Tensor:
    """Complex relative permittivity at freq_hz of a material following the ITU-R P.2040 law: eps_r =
    eps_r_1ghz (f / 1 GHz)^eps_r_exponent, sigma = sigma_1ghz (f / 1 GHz)^sigma_exponent [S/m]; broadcast,
    complex128 (differentiable in every torch argument)."""
    f = _f64(freq_hz)
    return permittivity(power_law(eps_r_1ghz, eps_r_exponent, f), power_law(sigma_1ghz, sigma_exponent, f), f)


def itu_law(name: str, freq_hz) -> tuple[np.ndarray, np.ndarray]:
    """(eps_r, sigma [S/m]) of a table material at freq_hz (the power law, extrapolated outside its range)."""
    a, b, c, d, _, _ = ITU_MATERIALS[material_key(name)]
    f = np.asarray(freq_hz, dtype=float)
    return power_law(a, b, f), power_law(c, d, f)


def itu_range_ghz(name: str) -> tuple[float, float]:
    """Frequency range [GHz] in which the ITU-R P.2040 law of `name` holds."""
    return ITU_MATERIALS[material_key(name)][4:6]


def fresnel(eta, cos_theta, k0=None, thickness_m=None) -> tuple[torch.Tensor, torch.Tensor]:
    """(R_TE, R_TM) of a half-space (thickness None or <= 0) or a slab, broadcasting all arguments.

    eta: complex relative permittivity (an infinite imaginary part means a perfect conductor);
    cos_theta: cosine of the incidence angle from the normal, clipped to [0, 1];
    k0: free-space wavenumber 2 pi f / c [rad/m] (needed for a slab); thickness_m: slab thickness [m].
    """
    eta = _c128(eta)
    c = _f64(cos_theta).clamp(0.0, 1.0)
    pec = ~torch.isfinite(eta)
    eta_f = torch.where(pec, torch.full_like(eta, 4.0), eta)  # placeholder, overwritten below
    # principal branch: Im <= 0 for lossy media (decaying wave). (eta - 1) + c^2, not eta - (1 - c^2): near grazing
    # 1 - c^2 rounds to 1 and a vacuum (eta = 1) would get root 0, hence r = 1, at the tables' last angle node
    root = torch.sqrt((eta_f - 1.0) + c * c)
    cc = c.to(torch.complex128)
    r_te = (cc - root) / (cc + root)
    r_tm = (eta_f * cc - root) / (eta_f * cc + root)
    # 0/0 only where root = c = 0, i.e. eta = 1 (a material that is vacuum) at grazing incidence: there is no
    # interface, so the limit along eta = 1 is 0 (no reflection, full transmission), as at every other angle
    bad = ~torch.isfinite(r_te) | ~torch.isfinite(r_tm)
    r_te = torch.where(bad, torch.zeros_like(r_te), r_te)
    r_tm = torch.where(bad, torch.zeros_like(r_tm), r_tm)
    if thickness_m is not None:
        if k0 is None:
            raise ValueError("a slab reflection coefficient needs k0")
        th = _f64(thickness_m)
        ph = _propagate(root, k0, th, 2.0)
        slab = th > 0
        r_te = torch.where(slab, r_te * (1.0 - ph) / (1.0 - r_te**2 * ph), r_te)
        r_tm = torch.where(slab, r_tm * (1.0 - ph) / (1.0 - r_tm**2 * ph), r_tm)
    shape = np.broadcast_shapes(tuple(r_te.shape), tuple(pec.shape))   # torch.broadcast_shapes imports sympy (1 s)
    r_te = torch.where(pec, torch.full(shape, -1.0 + 0j, dtype=torch.complex128), r_te.expand(shape))
    r_tm = torch.where(pec, torch.full(shape, 1.0 + 0j, dtype=torch.complex128), r_tm.expand(shape))
    return r_te, r_tm


def _propagate(root: torch.Tensor, k0, thickness_m: torch.Tensor, passes: float) -> torch.Tensor:
    """exp(-j passes q), q = k0 d root; the real exponent is clipped so huge losses give 0, not NaN."""
    arg = -1j * passes * _f64(k0) * thickness_m.clamp(min=0.0) * root
    return torch.exp(torch.complex(arg.real.clamp(min=-700.0), arg.imag))


def slab_transmission(eta, cos_theta, k0, thickness_m) -> tuple[torch.Tensor, torch.Tensor]:
    """(T_TE, T_TM) of a slab (ITU-R P.2040 multiple internal reflections), broadcast; complex128.

    A perfect conductor (infinite imaginary eta) transmits nothing."""
    eta = _c128(eta)
    pec = ~torch.isfinite(eta)
    eta_f = torch.where(pec, torch.full_like(eta, 4.0), eta)
    c = _f64(cos_theta).clamp(0.0, 1.0)
    root = torch.sqrt((eta_f - 1.0) + c * c)      # as in fresnel
    r_te, r_tm = fresnel(eta_f, c)
    th = _f64(thickness_m)
    ph = _propagate(root, k0, th, 2.0)
    half = _propagate(root, k0, th, 1.0)
    t_te = (1.0 - r_te**2) * half / (1.0 - r_te**2 * ph)
    t_tm = (1.0 - r_tm**2) * half / (1.0 - r_tm**2 * ph)
    zero = torch.zeros((), dtype=torch.complex128)
    return torch.where(pec, zero, t_te), torch.where(pec, zero, t_tm)


def co_polar_reflection(r_te: torch.Tensor, r_tm: torch.Tensor, te_share) -> torch.Tensor:
    """Scalar co-polarised reflection coefficient `te R_TE - (1 - te) R_TM`.

    te_share: the squared projection of the wave's polarisation on the TE direction of the plane of
    incidence (1: pure TE). The minus sign: the TM reference direction of the reflected wave is
    reversed against the incident one, so a perfect conductor gives -1 for every polarisation and
    at normal incidence the result is R_TE whatever te_share is."""
    te = _f64(te_share)
    return te * r_te - (1.0 - te) * r_tm


def specular_share(scattering):
    """sqrt(1 - S^2): the share of a surface's reflected field amplitude that stays specular for scattering
    coefficient S in [0, 1] (ITU-R P.2040's effective roughness: the power S^2 goes diffuse). S a torch tensor;
    values past 1 give 0, not NaN."""
    return torch.sqrt((1.0 - scattering ** 2).clamp(min=0.0))


def normal_incidence_reflection(eta, k0=None, thickness_m=None) -> torch.Tensor:
    """R_TE at normal incidence (equal to -R_TM there): the number a radio engineer reads as |Gamma|."""
    return fresnel(eta, 1.0, k0, thickness_m)[0]
