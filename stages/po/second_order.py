"""Second-order (double-bounce) term of the PO solver: GO on the first bounce, PO on the second.

Approximation (shooting-and-bouncing rays, exit-aperture PO, truncated at two bounces):
1. The incident wave is cut into square ray tubes of side `spacing_m` (default lambda_min / 4)
   on a plane across the object (far field: parallel rays; near field: rays from the Tx point,
   tubes widening with the path length).
2. Each tube's central ray is traced (Open3D) to its first hit on facet A, where the wave is
   reflected as geometric optics: mirror direction, the field's TE/TM parts times A's Fresnel
   coefficients (or the scalar -Gamma rule), tube mirrored.
3. The reflected ray is traced to facet B. The tube's footprint on B (a parallelogram: the tube
   cross-section projected along the reflected direction) carries PO currents from the reflected
   field, radiated toward the Rx with the closed-form parallelogram integral
   `area * sinc(k w.a/2) * sinc(k w.b/2)` (w = s_hat - reflected direction), if the Rx sees B's
   hit point (ray cast) from the lit side.
Not included: the first-bounce PO edge effects of partly hit tubes (a tube is in or out by its
central ray), third and higher bounces, diffraction (no edge-wave / PTD terms), creeping waves,
the GO blockage of the B -> Rx leg by the tube's own width. The first-order PO of every facet is
computed separately and added; the second-order sum only adds the A -> B -> Rx paths.
Near field: the reflected wave spreads from the image source (amplitude R_t / (t1 + t2)),
exact for flat A.
"""
from __future__ import annotations

import numpy as np

from .geometry import normalize, polarization_vector, sinc_u
from .solver import _dot, _sum_into, po_coefficients, reflect_field_basis

_PEC_GAMMA = (-1.0, 1.0)


def _basis(t_hat):
    z = np.array([0.0, 0.0, 1.0])
    u = np.cross(t_hat, z)
    if np.linalg.norm(u) < 1e-9:
        u = np.cross(t_hat, np.array([1.0, 0.0, 0.0]))
    u = u / np.linalg.norm(u)
    return u, np.cross(t_hat, u)


def _tube_rays(verts, tx_m, ref, R_t, near_field, spacing):
    """Rays for one aspect: origins, unit directions, cell sides su, sv (N,3) at the grid plane,
    distance rho from origin to the grid plane along each ray (inf for parallel rays)."""
    t_hat = (tx_m - ref) / R_t
    u, v = _basis(t_hat)
    rel = verts - ref
    if near_field:
        to_v = verts - tx_m
        depth = -(to_v @ t_hat)  # distance in front of tx along -t_hat
        front = depth > 1e-9
        if not front.any():
            return None
        proj = tx_m + to_v[front] * (R_t / depth[front])[:, None] - ref
        pu, pv = proj @ u, proj @ v
    else:
        pu, pv = rel @ u, rel @ v
    nu = max(1, int(np.ceil((pu.max() - pu.min()) / spacing)))
    nv = max(1, int(np.ceil((pv.max() - pv.min()) / spacing)))
    au = pu.min() + (np.arange(nu) + 0.5) * ((pu.max() - pu.min()) / nu if nu > 1 else 0.0)
    av = pv.min() + (np.arange(nv) + 0.5) * ((pv.max() - pv.min()) / nv if nv > 1 else 0.0)
    du = (pu.max() - pu.min()) / nu if pu.max() > pu.min() else spacing
    dv = (pv.max() - pv.min()) / nv if pv.max() > pv.min() else spacing
    A, B = np.meshgrid(au, av, indexing="ij")
    g = ref + A.reshape(-1, 1) * u + B.reshape(-1, 1) * v
    n = len(g)
    su = np.broadcast_to(du * u, (n, 3))
    sv = np.broadcast_to(dv * v, (n, 3))
    if near_field:
        d = g - tx_m
        rho = np.linalg.norm(d, axis=1)
        return np.broadcast_to(tx_m, (n, 3)).copy(), d / rho[:, None], su, sv, rho
    big = float(np.linalg.norm(rel, axis=1).max()) + 1.0
    return g + big * t_hat, np.broadcast_to(-t_hat, (n, 3)).copy(), su, sv, np.full(n, np.inf)


def double_bounce(verts, fcs, tab, refl, occ, tx, rx, ref, ks, pol_t, pol_r, *, near_field=False,
                  two_sided=True, spacing_m=None, chunk_elements=1 << 19, max_rays=1 << 18, amplitude_weight=None):
    """Second-order PO amplitude (M, K), same normalisation as po_scattered_field."""
    M, K = len(tx), len(ks)
    out = np.zeros((M, K), dtype=complex)
    spacing = float(spacing_m) if spacing_m else 0.25 * 2.0 * np.pi / float(np.max(ks))
    n_all = tab["n"]
    eps = 1e-5 * max(occ.size, 1e-3)
    R_t = np.linalg.norm(tx - ref, axis=1)
    R_r = np.linalg.norm(rx - ref, axis=1)
    batch: list = []
    nb = 0
    for m in range(M):
        rays = _tube_rays(verts, tx[m], ref, R_t[m], near_field, spacing)
        if rays is not None:
            batch.append((m, rays))
            nb += len(rays[0])
        if batch and (nb >= max_rays or m == M - 1):
            _trace_batch(out, batch, n_all, tab["c"], fcs, refl, occ, tx, rx, ref, R_t, R_r, ks, pol_t, pol_r,
                         near_field, two_sided, eps, chunk_elements, amplitude_weight)
            batch, nb = [], 0
    return out


def _trace_batch(out, batch, n_all, centres, fcs, refl, occ, tx, rx, ref, R_t, R_r, ks, pol_t, pol_r, near_field,
                 two_sided, eps, chunk_elements, amplitude_weight=None):
    mg = np.concatenate([np.full(len(r[0]), m) for m, r in batch])
    o = np.concatenate([r[0] for _, r in batch])
    d = np.concatenate([r[1] for _, r in batch])
    su = np.concatenate([r[2] for _, r in batch])
    sv = np.concatenate([r[3] for _, r in batch])
    rho = np.concatenate([r[4] for _, r in batch])
    # first bounce (GO). Near field: start the cast just in front of the object (float32 inside
    # Open3D), then recompute every hit point in float64 on the hit facet's plane.
    t0 = np.zeros(len(o))
    if near_field:
        t0 = np.maximum(0.0, _dot(ref - o, d) - occ.size - 1.0)
    t1, fa = occ.first_hit(o + t0[:, None] * d, d)
    ok = fa >= 0
    nA = n_all[np.maximum(fa, 0)]
    cosA = _dot(nA, d)
    ok &= np.abs(cosA) > 1e-9
    if not two_sided:
        ok &= cosA < 0
    sel = np.nonzero(ok)[0]
    mg, o, d, su, sv, rho, t1, fa = mg[sel], o[sel], d[sel], su[sel], sv[sel], rho[sel], t1[sel], fa[sel]
    nA = nA[sel] * -np.sign(cosA[sel])[:, None]  # facing the incoming ray
    t1 = _dot(centres[fa] - o, nA) / _dot(d, nA)  # exact plane hit (float64)
    pA = o + t1[:, None] * d
    d2 = d - 2.0 * _dot(d, nA)[:, None] * nA
    # second hit
    t2, fb = occ.first_hit(pA + eps * nA, d2)
    ok = fb >= 0
    nB = n_all[np.maximum(fb, 0)]
    cosB = _dot(nB, d2)
    ok &= np.abs(cosB) > 1e-6
    if not two_sided:
        ok &= cosB < 0
    sel = np.nonzero(ok)[0]
    if len(sel) == 0:
        return
    mg, d, su, sv, rho, t1, fa, nA, pA, d2, t2, fb = (x[sel] for x in (mg, d, su, sv, rho, t1, fa, nA, pA, d2, t2, fb))
    nB = nB[sel] * -np.sign(cosB[sel])[:, None]
    t2 = _dot(centres[fb] - pA, nB) / _dot(d2, nB)
    pB = pA + t2[:, None] * d2
    # toward the receiver
    if near_field:
        vr = rx[mg] - pB
        dist_r = np.linalg.norm(vr, axis=1)
        s_hat = vr / dist_r[:, None]
    else:
        s_hat = normalize(rx[mg] - ref)
    ok = _dot(nB, s_hat) > 0
    oB = pB + eps * nB
    if near_field:
        ok &= occ.unoccluded(oB, rx[mg] - oB, tfar=1.0 - 1e-7)
    else:
        ok &= occ.unoccluded(oB, s_hat)
    sel = np.nonzero(ok)[0]
    if len(sel) == 0:
        return
    mg, d, su, sv, rho, t1, fa, nA, pA, d2, t2, fb, nB, pB, s_hat = (
        x[sel] for x in (mg, d, su, sv, rho, t1, fa, nA, pA, d2, t2, fb, nB, pB, s_hat))
    path = t1 + t2
    if near_field:
        dist_r = np.linalg.norm(rx[mg] - pB, axis=1)
        phase_len = -(path + dist_r - R_t[mg] - R_r[mg])
        amp = (R_t[mg] / path) * (R_r[mg] / dist_r)
        scale = path / rho
    else:
        phase_len = _dot(-d, pA - ref) - t2 + _dot(s_hat, pB - ref)
        amp = np.ones(len(mg))
        scale = np.ones(len(mg))
    # tube footprint on B: mirror at A, project along d2 onto B's plane
    def mirror(x):
        return x - 2.0 * _dot(x, nA)[:, None] * nA

    def project(x):
        return x - (_dot(x, nB) / _dot(d2, nB))[:, None] * d2

    a_vec = project(mirror(su * scale[:, None]))
    b_vec = project(mirror(sv * scale[:, None]))
    area = np.linalg.norm(np.cross(a_vec, b_vec), axis=1)
    w = s_hat - d2
    wa, wb = _dot(w, a_vec), _dot(w, b_vec)
    # fields
    e_inc = polarization_vector(d, pol_t)
    p_hat = polarization_vector(-s_hat, pol_r)
    _, (b_te, b_tm) = reflect_field_basis(nA, d, e_inc)
    c_te = po_coefficients(nB, d2, s_hat, b_te, p_hat)  # (P,3)
    c_tm = po_coefficients(nB, d2, s_hat, b_tm, p_hat)
    cosA_abs = np.abs(_dot(d, nA))
    cosB_abs = np.abs(_dot(d2, nB))

    def kernel(kidx):
        k = ks[kidx][None, :]
        foot = sinc_u(0.5 * k * wa[:, None]) * sinc_u(0.5 * k * wb[:, None])
        if refl.material_mode:
            ra_te, ra_tm = refl.te_tm(kidx, fa, cosA_abs)
            rb_te, rb_tm = refl.te_tm(kidx, fb, cosB_abs)
            fac = ra_te * (c_te[:, 0:1] + rb_te * c_te[:, 1:2] + rb_tm * c_te[:, 2:3]) + \
                ra_tm * (c_tm[:, 0:1] + rb_te * c_tm[:, 1:2] + rb_tm * c_tm[:, 2:3])
        else:
            pec = _PEC_GAMMA[0] * (c_te[:, 0] - c_te[:, 1] + c_te[:, 2]) + \
                _PEC_GAMMA[1] * (c_tm[:, 0] - c_tm[:, 1] + c_tm[:, 2])
            fac = refl.scalar(kidx, fa) * refl.scalar(kidx, fb) * pec[:, None]
        return foot * fac

    base = amp * area
    if amplitude_weight is not None:
        base = base * np.asarray(amplitude_weight(mg, d, -s_hat))
    _sum_into(out, mg, ks, chunk_elements, kernel, phase_len, base)
