"""The physical-optics currents of a lit facet and the sum of facet contributions, shared by the first-order solver
(solver.py) and the multi-bounce tubes (multi_bounce.py), which both import them from here.

`po_coefficients` gives the far-field factor of the PO currents split over the reflection coefficients
(c0 + R_TE c_TE + R_TM c_TM); `reflect_field_basis` the reflected field in the same split; `_sum_into` adds the
facet contributions per aspect and frequency (normalisation: solver.py's docstring).
"""
from __future__ import annotations

import math

import numpy as np

from rfir_core.physics.polarisation import mirror_direction, reflection_basis

_SQRT_4PI = math.sqrt(4.0 * math.pi)


def _dot(a, b):
    return np.einsum("ij,ij->i", a, b)


def _radiate(n, s_hat, p_hat, e, h):
    """p . [s x (s x (n x H) - n x E)] for surface fields E, eta*H (per row): the PO far-field
    vector (J = n x H, M = -n x E, eta J and M radiating toward s), projected on p (p . s = 0).
    Equal to -p.(n x H) - (n x E).(p x s)."""
    return -_dot(p_hat, np.cross(n, h)) - _dot(np.cross(n, e), np.cross(p_hat, s_hat))


def po_coefficients(n, i_hat, s_hat, e_inc, p_hat):
    """(P,3) coefficients (c0, c_TE, c_TM) with PO far-field factor = c0 + R_TE c_TE + R_TM c_TM.

    n: facet normals facing the incident wave (n . i_hat < 0), i_hat: propagation direction of the
    incident wave, s_hat: scattering direction, e_inc: incident E (any real vector, linear),
    p_hat: receive polarisation. Perfect conductor: R_TE = -1, R_TM = +1.
    """
    r_hat = mirror_direction(i_hat, n)
    # at normal incidence the incident field's own direction is taken as TE (any tangent works: R_TM = -R_TE there)
    e_te, e_tm_i, e_tm_r = reflection_basis(i_hat, n, r_hat, fallback=e_inc)
    a_te = _dot(e_inc, e_te)
    a_tm = _dot(e_inc, e_tm_i)
    c0 = _radiate(n, s_hat, p_hat, e_inc, np.cross(i_hat, e_inc))
    c_te = a_te * _radiate(n, s_hat, p_hat, e_te, np.cross(r_hat, e_te))
    c_tm = a_tm * _radiate(n, s_hat, p_hat, e_tm_r, np.cross(r_hat, e_tm_r))
    return np.stack([c0, c_te, c_tm], axis=1)


def reflect_field_basis(n, i_hat, e_inc):
    """Reflected-field basis at a facet: (r_hat, [a_te * e_te, a_tm * e_tm_r]) so that the reflected
    E = R_TE * b0 + R_TM * b1 (perfect conductor: -b0 + b1 = -e + 2 (e.n) n)."""
    r_hat = mirror_direction(i_hat, n)
    # at normal incidence the incident field's own direction is taken as TE (any tangent works: R_TM = -R_TE there)
    e_te, e_tm_i, e_tm_r = reflection_basis(i_hat, n, r_hat, fallback=e_inc)
    return r_hat, (_dot(e_inc, e_te)[:, None] * e_te, _dot(e_inc, e_tm_i)[:, None] * e_tm_r)


def _sum_into(out, mg, ks, chunk_elements, kernel, phase_len, base):
    """out[m, k] += sum over pairs of (j k / sqrt(4 pi)) * base * exp(j k phase_len) * kernel(kidx)."""
    P = len(mg)
    if P == 0:
        return
    order = np.argsort(mg, kind="stable")
    if np.any(order != np.arange(P)):
        raise AssertionError("pairs must be grouped by aspect")  # np.nonzero gives them sorted
    starts = np.concatenate([[0], np.nonzero(np.diff(mg))[0] + 1])
    rows = mg[starts]
    kc = max(1, int(chunk_elements) // P)
    for k0 in range(0, len(ks), kc):
        kidx = np.arange(k0, min(len(ks), k0 + kc))
        k = ks[kidx]
        val = kernel(kidx)
        if phase_len is not None:
            val *= np.exp(1j * np.outer(phase_len, k))
        val *= base[:, None]
        val *= (1j * k / _SQRT_4PI)[None, :]
        out[np.ix_(rows, kidx)] += np.add.reduceat(val, starts, axis=0)
