"""Polarisation: an antenna's V/H field direction and the TE/TM basis of a reflection, one definition each.

Every function takes numpy arrays or torch tensors ([..., 3] unit vectors, world frame, +z up) and returns the
same kind.

V/H (docs/physics.md section 1): Sionna RT's convention. A "V" antenna radiates its field along theta-hat of
the direction k it sends the wave in (theta measured from +z): in the vertical plane through k, pointing down at
the horizon; "H" along phi-hat = k x theta-hat, horizontal. Straight up or down, where theta-hat is undefined,
V is the part of +x across k (theta-hat's limit for phi = 0 looking up) and H = k x V. Transmitter and receiver
use the same rule, as Sionna does; a co-polarised link's field does not depend on the sign chosen, since it
enters at both ends.

TE/TM: a wave travelling along k_in meets a plane of unit normal n; e_TE = (k_in x n) / |k_in x n| is
perpendicular to the plane of incidence, e_TM = k x e_TE lies in it, for the incident direction and the
outgoing one (mirrored for a reflection, the same for a transmission) alike: the reference of
physics.materials' R_TE, R_TM (a perfect conductor: R_TE = -1, R_TM = +1). At normal incidence, where the plane
of incidence is undefined, any direction across k serves (R_TM = -R_TE there and T_TM = T_TE): a caller may
pass the one it wants (`fallback`), else the part of +x (of +y when k is near x) across k is used.
"""
from __future__ import annotations

import numpy as np
import torch

POLARISATIONS = ("V", "H")
_DEGENERATE = 1e-9   # |k x z| or |k x n| below this: the direction is taken as exactly vertical / normal


def _is_torch(x) -> bool:
    return isinstance(x, torch.Tensor)


def _cross(a, b):
    return torch.linalg.cross(*torch.broadcast_tensors(a, b), dim=-1) if _is_torch(a) else np.cross(a, b)


def _dot(a, b):
    return (a * b).sum(-1, keepdims=True) if not _is_torch(a) else (a * b).sum(-1, keepdim=True)


def _norm(a):
    return a.norm(dim=-1, keepdim=True) if _is_torch(a) else np.linalg.norm(a, axis=-1, keepdims=True)


def _where(cond, a, b):
    return torch.where(cond, a, b) if _is_torch(a) else np.where(cond, a, b)


def _axis(k, index: int):
    """The unit axis `index` broadcast to k's shape, in k's kind and dtype."""
    if _is_torch(k):
        e = torch.zeros(k.shape, dtype=k.dtype, device=k.device)
    else:
        e = np.zeros(np.shape(k))
    e[..., index] = 1.0
    return e


def _unit(a):
    n = _norm(a)
    return a / (n.clamp(min=1e-300) if _is_torch(a) else np.maximum(n, 1e-300))


def _across(k, v):
    """The part of v across unit k, unit length."""
    return _unit(v - _dot(v, k) * k)


def antenna_polarisation(k, pol: str):
    """[..., 3] unit field direction of a `pol` ("V" or "H") antenna sending its wave along unit k [..., 3]
    (module docstring: V = theta-hat, H = phi-hat = k x V)."""
    pol = str(pol).upper()
    if pol not in POLARISATIONS:
        raise ValueError(f"polarisation must be 'V' or 'H', got {pol!r}")
    if not _is_torch(k):
        k = np.asarray(k, dtype=float)
    z = _axis(k, 2)
    theta_hat = k * _dot(k, z) - z                    # |.| = sin(theta)
    vertical = _norm(theta_hat) < _DEGENERATE
    v = _unit(theta_hat)
    if vertical.any():
        v = _where(vertical, _across(k, _axis(k, 0)), v)
    return v if pol == "V" else _cross(k, v)


def reflection_basis(k_in, normal, k_out=None, fallback=None):
    """(e_TE, e_TM_in, e_TM_out) [..., 3] of a wave along unit k_in [..., 3] meeting a plane of unit normal
    [..., 3] (either side), leaving along k_out (None: the mirror image of k_in, a reflection). fallback
    [..., 3] (optional): the TE direction where the incidence is normal (its part across k_in is used)."""
    if not _is_torch(k_in):
        k_in, normal = np.asarray(k_in, dtype=float), np.asarray(normal, dtype=float)
    if k_out is None:
        k_out = mirror_direction(k_in, normal)
    e_te = _cross(k_in, normal)
    normal_incidence = _norm(e_te) < _DEGENERATE
    if normal_incidence.any():
        if fallback is None:
            near_x = (k_in[..., :1] ** 2) > 0.81
            fallback = _where(near_x, _axis(k_in, 1), _axis(k_in, 0))
        # the fallback's part across k_in; where that vanishes too (fallback along k_in), +z's or +x's part
        alt = fallback - _dot(fallback, k_in) * k_in
        for axis in (2, 0):
            alt = _where(_norm(alt) < _DEGENERATE, _axis(k_in, axis) - _dot(_axis(k_in, axis), k_in) * k_in, alt)
        e_te = _where(normal_incidence, alt, e_te)
    e_te = _unit(e_te)
    return e_te, _cross(k_in, e_te), _cross(k_out, e_te)


def mirror_direction(k, normal):
    """k mirrored in a plane of unit normal [..., 3]: k - 2 (k . n) n."""
    return k - 2.0 * _dot(k, normal) * normal


def te_share(k_in, normal, pol: str):
    """[...] squared projection of a `pol` antenna's field, sent along k_in, on the TE direction of a plane of
    unit normal (0.5 where the incidence is normal: TE and TM reflect alike there). Its sign convention drops
    out (squared), so V/H only decide which plane the field lies in."""
    p = antenna_polarisation(k_in, pol)
    e_te = _cross(k_in, normal)
    s = _norm(e_te)
    e_te = e_te / (s.clamp(min=1e-12) if _is_torch(s) else np.maximum(s, 1e-12))
    share = _dot(p, e_te)[..., 0] ** 2
    if _is_torch(share):
        return torch.where(s[..., 0] < _DEGENERATE, torch.full_like(share, 0.5), share.clamp(0.0, 1.0))
    return np.where(s[..., 0] < _DEGENERATE, 0.5, np.clip(share, 0.0, 1.0))
