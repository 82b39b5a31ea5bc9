"""Second-order (double-bounce) term of the PO solver: GO on the first bounce, PO on the second.

Approximation (shooting-and-bouncing rays, exit-aperture PO, truncated at two bounces):
1. The incident wave is cut into square ray tubes of side `spacing_m` (default `auto_tube_spacing`:
   lambda_min / 20, wider for objects too large for that) on a plane across the object (far field:
   parallel rays; near field: rays from the Tx point, tubes widening with the path length). A tube
   whose footprint on either facet it meets is longer than the side (a grazing bounce) is cut into
   sub-tubes, each traced again.
2. Each tube's central ray is traced (Open3D) to its first hit on facet A, where the wave is
   reflected as geometric optics: mirror direction, the field's TE/TM parts times A's Fresnel
   coefficients (or the scalar -Gamma rule), tube mirrored.
3. The reflected ray is traced to facet B. The tube's footprint on B (a parallelogram: the tube
   cross-section projected along the reflected direction) carries PO currents from the reflected
   field, radiated toward the Rx with the closed-form parallelogram integral
   `area * sinc(k w.a/2) * sinc(k w.b/2)` (w = s_hat - reflected direction), if the Rx sees B's
   hit point (ray cast) from the lit side.
Not included: the first-bounce PO edge effects of partly hit tubes (a tube is in or out by its
central ray; errors of order side / facet size), third and higher bounces, diffraction (no
edge-wave / PTD terms), creeping waves, the GO blockage of the B -> Rx leg by the tube's own width.
The first-order PO of every facet is computed separately and added; the second-order sum only adds
the A -> B -> Rx paths.
Near field: the reflected wave spreads from the image source (amplitude R_t / (t1 + t2)),
exact for flat A.
"""
from __future__ import annotations

import numpy as np

from .geometry import normalize, polarization_vector, sinc_u
from .solver import _dot, _sum_into, po_coefficients, reflect_field_basis

_PEC_GAMMA = (-1.0, 1.0)
REFINE_MAX = 32     # a tube side is cut into at most this many parts where its footprint is long (grazing bounces)
TUBES_PER_WAVELENGTH = 20   # default tube side lambda_min / 20: converged within ~0.3 dB MAE on the lego (docs/po.md)
MAX_TUBES = 1 << 17         # ... unless the object's grid of tubes would exceed this many per aspect


def auto_tube_spacing(verts: np.ndarray, ks) -> float:
    """The default tube side, m: lambda_min / TUBES_PER_WAVELENGTH, widened for large objects so that
    a square grid over the object's extent (twice its bounding-sphere radius) holds at most MAX_TUBES
    tubes. Where a tube's footprint is longer than this side (grazing bounces) it is split
    (`_footprint_parts`), so the widened side costs accuracy at tube edges only."""
    lam_min = 2.0 * np.pi / float(np.max(ks))
    extent = 2.0 * float(np.linalg.norm(verts - verts.mean(0), axis=1).max()) if len(verts) else 0.0
    return max(lam_min / TUBES_PER_WAVELENGTH, extent / np.sqrt(MAX_TUBES))


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
    spacing = float(spacing_m) if spacing_m else auto_tube_spacing(verts, ks)
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
                         near_field, two_sided, eps, chunk_elements, spacing, amplitude_weight)
            batch, nb = [], 0
    return out


def _first_facet(occ, o, d, ref, near_field):
    """The first facet [N] (-1: none) hit by rays o + t d. Near field: the cast starts just in front of the
    object (float32 inside Open3D); the caller computes the hit point in float64 on the facet's plane."""
    t0 = np.maximum(0.0, _dot(ref - o, d) - occ.size - 1.0) if near_field else np.zeros(len(o))
    return occ.first_hit(o + t0[:, None] * d, d)[1]


def _two_bounces(occ, rays, n_all, centres, ref, near_field, two_sided, eps) -> dict:
    """Trace rays (a dict of [N] / [N, 3] arrays: mg, o, d, su, sv, rho) to their first facet A, reflect
    them (GO) and trace them to B; keep those that reach B and add t1, fa, nA (facing the ray), pA,
    d2, t2, fb, nB, pB (hit points in float64 on the facets' planes)."""
    o, d = rays["o"], rays["d"]
    fa = _first_facet(occ, o, d, ref, near_field)
    nA = n_all[np.maximum(fa, 0)]
    cosA = _dot(nA, d)
    ok = (fa >= 0) & (np.abs(cosA) > 1e-9)
    if not two_sided:
        ok &= cosA < 0
    sel = np.nonzero(ok)[0]
    r = {k: v[sel] for k, v in rays.items()}
    fa = fa[sel]
    nA = nA[sel] * -np.sign(cosA[sel])[:, None]  # facing the incoming ray
    t1 = _dot(centres[fa] - r["o"], nA) / _dot(r["d"], nA)  # exact plane hit (float64)
    pA = r["o"] + t1[:, None] * r["d"]
    d2 = r["d"] - 2.0 * _dot(r["d"], nA)[:, None] * nA
    t2, fb = occ.first_hit(pA + eps * nA, d2)
    nB = n_all[np.maximum(fb, 0)]
    cosB = _dot(nB, d2)
    ok = (fb >= 0) & (np.abs(cosB) > 1e-6)
    if not two_sided:
        ok &= cosB < 0
    sel = np.nonzero(ok)[0]
    r = {k: v[sel] for k, v in r.items()}
    r.update(t1=t1[sel], fa=fa[sel], nA=nA[sel], pA=pA[sel], d2=d2[sel], fb=fb[sel])
    r["nB"] = nB[sel] * -np.sign(cosB[sel])[:, None]
    r["t2"] = _dot(centres[r["fb"]] - r["pA"], r["nB"]) / _dot(r["d2"], r["nB"])
    r["pB"] = r["pA"] + r["t2"][:, None] * r["d2"]
    return r


def _footprint_parts(r: dict, near_field: bool, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Parts [N] (int, >= 1) to cut each side of the tubes of `r` (see _two_bounces) into, so that no
    sub-tube's footprint on A or on B is longer than `spacing`.

    A tube is in or out by its central ray, so a tube meeting a facet at grazing incidence stands for
    a strip spacing / cos(theta) long on it: a 1.3 cm tube seen at 2 degrees covers 37 cm, a whole
    brick top and the side of the next brick, and returns the area of the facet it happens to hit.
    A side x of the tube (perpendicular to the ray) lands on A's plane as
    |x_A| = sqrt(|x|^2 + ((x . n_A) / cos theta_A)^2), and on B as the footprint the sum uses
    (x mirrored at A, projected along the reflected ray onto B)."""
    grow_a = (r["t1"] / r["rho"])[:, None] if near_field else 1.0          # near field: tubes widen with the path
    grow_b = ((r["t1"] + r["t2"]) / r["rho"])[:, None] if near_field else 1.0
    cos_a = np.abs(_dot(r["nA"], r["d"])).clip(1e-3, 1.0)
    out = []
    for side in (r["su"], r["sv"]):
        x = side * grow_a
        on_a = np.sqrt(_dot(x, x) + (_dot(x, r["nA"]) / cos_a) ** 2)
        m = side * grow_b
        m = m - 2.0 * _dot(m, r["nA"])[:, None] * r["nA"]
        m = m - (_dot(m, r["nB"]) / _dot(r["d2"], r["nB"]))[:, None] * r["d2"]
        on_b = np.sqrt(_dot(m, m))
        out.append(np.clip(np.ceil(np.maximum(on_a, on_b) / spacing - 1e-9), 1, REFINE_MAX).astype(int))
    return out[0], out[1]


def _sub_tubes(r: dict, n_u: np.ndarray, n_v: np.ndarray, near_field: bool) -> dict:
    """Rays of the n_u x n_v sub-tubes of each tube of `r` (sides su / n_u, sv / n_v)."""
    counts = n_u * n_v
    tube = np.repeat(np.arange(len(counts)), counts)
    k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)   # sub-tube index in its tube
    nu_t, nv_t = n_u[tube], n_v[tube]
    a = ((k // nv_t) + 0.5) / nu_t - 0.5
    b = ((k % nv_t) + 0.5) / nv_t - 0.5
    su, sv, o, d, rho = (r[key][tube] for key in ("su", "sv", "o", "d", "rho"))
    off = a[:, None] * su + b[:, None] * sv
    sub = {"mg": r["mg"][tube], "su": su / nu_t[:, None], "sv": sv / nv_t[:, None]}
    if near_field:                                              # rays from the Tx through the sub-cells' centres
        ray = rho[:, None] * d + off
        sub_rho = np.linalg.norm(ray, axis=1)
        sub.update(o=o, d=ray / sub_rho[:, None], rho=sub_rho)
    else:                                                       # parallel rays
        sub.update(o=o + off, d=d, rho=rho)
    return sub


def _trace_batch(out, batch, n_all, centres, fcs, refl, occ, tx, rx, ref, R_t, R_r, ks, pol_t, pol_r, near_field,
                 two_sided, eps, chunk_elements, spacing, amplitude_weight=None):
    rays = {"mg": np.concatenate([np.full(len(r[0]), m) for m, r in batch])}
    for i, key in enumerate(("o", "d", "su", "sv", "rho")):
        rays[key] = np.concatenate([r[i] for _, r in batch])
    r = _two_bounces(occ, rays, n_all, centres, ref, near_field, two_sided, eps)
    # tubes whose footprint on A or B is longer than the spacing (grazing bounces) are cut into
    # sub-tubes, each traced again (one level; it may hit other facets)
    n_u, n_v = _footprint_parts(r, near_field, spacing)
    split = (n_u > 1) | (n_v > 1)
    if split.any():
        sub = _two_bounces(occ, _sub_tubes({k: v[split] for k, v in r.items()}, n_u[split], n_v[split], near_field),
                           n_all, centres, ref, near_field, two_sided, eps)
        order = np.argsort(np.concatenate([r["mg"][~split], sub["mg"]]), kind="stable")  # sums need rays grouped by aspect
        r = {k: np.concatenate([r[k][~split], sub[k]])[order] for k in r}
    if len(r["mg"]) == 0:
        return
    mg, d, su, sv, rho, t1, fa, nA, pA, d2, t2, fb, nB, pB = (
        r[k] for k in ("mg", "d", "su", "sv", "rho", "t1", "fa", "nA", "pA", "d2", "t2", "fb", "nB", "pB"))
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
