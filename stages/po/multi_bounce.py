"""Multiple-bounce terms of the PO solver: GO on every bounce but the last, PO on the last.

Approximation (shooting-and-bouncing rays, PO radiation of every bounce, truncated at `max_bounces`):
1. The incident wave is cut into square ray tubes of side `spacing_m` (default `auto_tube_spacing`:
   lambda_min / 20, wider for objects too large for that) on a plane across the object (far field:
   parallel rays; near field: rays from the Tx point, tubes widening with the path length). A tube
   whose footprint on any facet it meets is longer than the side (a grazing bounce) is cut into
   sub-tubes, each traced again.
2. Each tube's central ray is traced (Open3D) to its first hit on facet A, where the wave is
   reflected as geometric optics (`_trace`): mirror direction, the field's TE/TM parts times A's
   Fresnel coefficients (or the scalar -Gamma rule), tube mirrored. The reflected ray is traced to
   B, reflected the same way, traced to C, and so on up to `max_bounces` facets.
3. Every facet after the first radiates (SBR sums all bounces): the tube's footprint on the b-th
   facet (a parallelogram: the tube cross-section mirrored at the facets before and projected along
   the ray onto it) carries PO currents from the field reflected b - 1 times, radiated toward the Rx
   with the closed-form parallelogram integral `area * sinc(k w.a/2) * sinc(k w.b/2)` (w = s_hat -
   the ray's direction), if the Rx sees the hit point (ray cast) from the lit side. So
   max_bounces = 2 adds the A -> B -> Rx paths, 3 also the A -> B -> C -> Rx paths (a trihedral's
   flash).
Not included: the PO edge effects of partly hit tubes (a tube is in or out by its central ray;
errors of order side / facet size), bounces past `max_bounces`, diffraction (no edge-wave / PTD
terms), creeping waves, the GO blockage of the last leg to the Rx by the tube's own width. The
first-order PO of every facet is computed separately and added; this sum adds the paths of two
and more facets.
Near field: the wave reflected b - 1 times spreads from the image source (amplitude
R_t / (t1 + ... + tb), the path length from the Tx to the b-th hit), exact for flat facets.
"""
from __future__ import annotations

import numpy as np

from rfir_core.physics.polarisation import antenna_polarisation

from .geometry import normalize, sinc_u
from .currents import _dot, _sum_into, po_coefficients, reflect_field_basis

REFINE_MAX = 32     # a tube side is cut into at most this many parts where its footprint is long (grazing bounces)
TUBES_PER_WAVELENGTH = 20   # default tube side lambda_min / 20: finer tubes change the sum little (docs/po.md)
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


def multi_bounce(verts, fcs, tab, refl, occ, tx, rx, ref, ks, pol_t, pol_r, *, max_bounces=2, near_field=False,
                 two_sided=True, spacing_m=None, chunk_elements=1 << 19, max_rays=1 << 18, amplitude_weight=None):
    """PO amplitude (M, K) of the paths over 2 to max_bounces facets, same normalisation as po_scattered_field.

    tab: facet table of (verts, fcs) (normals, centroids); refl: the solver's _Reflection; occ: its
    Occluder; tx, rx (M, 3) m; ref (3,) m; ks (K,) rad/m; max_bounces >= 2."""
    if int(max_bounces) < 2:
        raise ValueError(f"max_bounces must be >= 2 (got {max_bounces}); first order alone is second_order=False")
    M, K = len(tx), len(ks)
    out = np.zeros((M, K), dtype=complex)
    spacing = float(spacing_m) if spacing_m else auto_tube_spacing(verts, ks)
    eps = 1e-5 * max(occ.size, 1e-3)
    R_t = np.linalg.norm(tx - ref, axis=1)
    R_r = np.linalg.norm(rx - ref, axis=1)
    ctx = dict(n_all=tab["n"], centres=tab["c"], refl=refl, occ=occ, tx=tx, rx=rx, ref=ref, R_t=R_t, R_r=R_r, ks=ks,
               pol_t=pol_t, pol_r=pol_r, near_field=near_field, two_sided=two_sided, eps=eps,
               chunk_elements=chunk_elements, spacing=spacing, amplitude_weight=amplitude_weight,
               max_bounces=int(max_bounces))
    batch: list = []
    nb = 0
    for m in range(M):
        rays = _tube_rays(verts, tx[m], ref, R_t[m], near_field, spacing)
        if rays is not None:
            batch.append((m, rays))
            nb += len(rays[0])
        if batch and (nb >= max_rays or m == M - 1):
            _trace_batch(out, batch, ctx)
            batch, nb = [], 0
    return out


def _first_facet(occ, o, d, ref, near_field):
    """The first facet [N] (-1: none) hit by rays o + t d. Near field: the cast starts just in front of the
    object (float32 inside Open3D); the caller computes the hit point in float64 on the facet's plane."""
    t0 = np.maximum(0.0, _dot(ref - o, d) - occ.size - 1.0) if near_field else np.zeros(len(o))
    return occ.first_hit(o + t0[:, None] * d, d)[1]


def _mirror(x, n):
    """x (N,3) mirrored at planes of unit normals n (N,3): the GO reflection of a direction or a tube side."""
    return x - 2.0 * _dot(x, n)[:, None] * n


def _trace(occ, rays, n_all, centres, ref, near_field, two_sided, eps, max_bounces) -> dict:
    """Trace rays (a dict of [N] / [N, 3] arrays: mg, o, d, su, sv, rho) from facet to facet, reflecting
    them (GO mirror) at each, up to max_bounces = B facets. Keeps the rays that reach a second facet and
    adds their history, padded to B hits: nhit [N] (2..B), f [N, B] facets (-1 past nhit), n [N, B, 3]
    normals facing the ray (0 past nhit), p [N, B, 3] hit points (float64, on the facets' planes),
    t [N, B] leg lengths, m (t[:, 0] from o), dirs [N, B + 1, 3] (dirs[:, j] arrives at hit j; dirs[:, 0] = d)."""
    B = max_bounces
    steps = []                                               # per hit: (rows of `rays` still travelling, f, n, p, t, reflected d)
    idx, o, d, n_prev = np.arange(len(rays["o"])), rays["o"], rays["d"], None
    for j in range(B):
        if j == 0:
            fj, tol = _first_facet(occ, o, d, ref, near_field), 1e-9
        else:   # off the facet just left, so the cast does not hit it again
            fj, tol = occ.first_hit(o + eps * n_prev, d)[1], 1e-6
        nj = n_all[np.maximum(fj, 0)]
        cos = _dot(nj, d)
        ok = (fj >= 0) & (np.abs(cos) > tol)
        if not two_sided:
            ok &= cos < 0
        sel = np.nonzero(ok)[0]
        if len(sel) == 0:
            break
        idx, o, d, fj = idx[sel], o[sel], d[sel], fj[sel]
        nj = nj[sel] * -np.sign(cos[sel])[:, None]            # facing the incoming ray
        tj = _dot(centres[fj] - o, nj) / _dot(d, nj)          # exact plane hit (float64)
        pj = o + tj[:, None] * d
        d_next = _mirror(d, nj)
        steps.append((idx, fj, nj, pj, tj, d_next))
        o, d, n_prev = pj, d_next, nj
    # history of the rays that reach a second facet, padded to B hits (built for those rays only: most
    # tubes of an aspect miss the object or leave it after one hit)
    keep = steps[1][0] if len(steps) > 1 else np.zeros(0, dtype=np.int64)
    K = len(keep)
    r = {k: v[keep] for k, v in rays.items()}
    f_h = np.full((K, B), -1, dtype=np.int64)
    n_h, p_h = np.zeros((K, B, 3)), np.zeros((K, B, 3))
    t_h, dirs = np.zeros((K, B)), np.zeros((K, B + 1, 3))
    dirs[:, 0] = r["d"]
    nhit = np.zeros(K, dtype=int)
    for j, (ij, fj, nj, pj, tj, dn) in enumerate(steps):
        at = np.searchsorted(ij, keep) if j == 0 else np.searchsorted(keep, ij)   # rows are sorted
        src = at if j == 0 else slice(None)
        dst = slice(None) if j == 0 else at
        f_h[dst, j], n_h[dst, j], p_h[dst, j], t_h[dst, j], dirs[dst, j + 1] = fj[src], nj[src], pj[src], tj[src], dn[src]
        nhit[dst] = j + 1
    r.update(nhit=nhit, f=f_h, n=n_h, p=p_h, t=t_h, dirs=dirs)
    return r


def _footprint_parts(r: dict, near_field: bool, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Parts [N] (int, >= 1) to cut each side of the tubes of `r` (see _trace) into, so that no sub-tube's
    footprint on any facet it hits is longer than `spacing`.

    A tube is in or out by its central ray, so a tube meeting a facet at grazing incidence stands for
    a strip spacing / cos(theta) long on it: a 1.3 cm tube seen at 2 degrees covers 37 cm, a whole
    brick top and the side of the next brick, and returns the area of the facet it happens to hit.
    A side x of the tube (perpendicular to the ray) lands on the first facet's plane as
    |x_A| = sqrt(|x|^2 + ((x . n_A) / cos theta_A)^2), and on each later facet as the footprint the sum
    uses (x mirrored at the facets before, projected along the ray onto the facet)."""
    n, dirs, nhit = r["n"], r["dirs"], r["nhit"]
    reach = np.cumsum(r["t"], axis=1) / r["rho"][:, None] if near_field else None   # near field: tubes widen
    cos_a = np.abs(_dot(n[:, 0], r["d"])).clip(1e-3, 1.0)
    out = []
    for side in (r["su"], r["sv"]):
        x = side * reach[:, 0:1] if near_field else side
        longest = np.sqrt(_dot(x, x) + (_dot(x, n[:, 0]) / cos_a) ** 2)
        m = side
        for j in range(1, n.shape[1]):
            on = nhit > j
            if not on.any():
                break
            m = _mirror(m, n[:, j - 1])   # n = 0 past a ray's last hit: no change
            x = m * reach[:, j:j + 1] if near_field else m
            den = np.where(on, _dot(dirs[:, j], n[:, j]), 1.0)
            x = x - (_dot(x, n[:, j]) / den)[:, None] * dirs[:, j]
            longest = np.where(on, np.maximum(longest, np.sqrt(_dot(x, x))), longest)
        out.append(np.clip(np.ceil(longest / spacing - 1e-9), 1, REFINE_MAX).astype(int))
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


def _trace_batch(out, batch, ctx):
    rays = {"mg": np.concatenate([np.full(len(r[0]), m) for m, r in batch])}
    for i, key in enumerate(("o", "d", "su", "sv", "rho")):
        rays[key] = np.concatenate([r[i] for _, r in batch])
    def trace(rays):
        return _trace(ctx["occ"], rays, ctx["n_all"], ctx["centres"], ctx["ref"], ctx["near_field"], ctx["two_sided"],
                      ctx["eps"], ctx["max_bounces"])

    r = trace(rays)
    # tubes whose footprint on any facet is longer than the spacing (grazing bounces) are cut into
    # sub-tubes, each traced again (one level; it may hit other facets)
    n_u, n_v = _footprint_parts(r, ctx["near_field"], ctx["spacing"])
    split = (n_u > 1) | (n_v > 1)
    if split.any():
        sub = trace(_sub_tubes({k: v[split] for k, v in r.items()}, n_u[split], n_v[split], ctx["near_field"]))
        order = np.argsort(np.concatenate([r["mg"][~split], sub["mg"]]), kind="stable")  # sums need rays grouped by aspect
        r = {k: np.concatenate([r[k][~split], sub[k]])[order] for k in r}
    for b in range(2, ctx["max_bounces"] + 1):   # every bounce radiates
        sel = np.nonzero(r["nhit"] >= b)[0]
        if len(sel):
            _radiate_bounce(out, {k: v[sel] for k, v in r.items()}, b, ctx)


def _go_te_tm(refl, kidx, fidx, cos_theta):
    """(R_TE, R_TM), each (P, len(kidx)), of the GO reflection at facets fidx: the facets' Fresnel
    coefficients, or for a scalar Gamma the perfect-conductor pair (-1, +1) times -Gamma."""
    if refl.material_mode:
        return refl.te_tm(kidx, fidx, cos_theta)
    g = refl.scalar(kidx, fidx)
    return g, -g


def _radiate_bounce(out, r, b, ctx):
    """Add the PO field radiated toward the Rx by the footprints of tubes `r` (see _trace, all with
    nhit >= b) on their b-th facet, lit by the incident field reflected (GO) at the b - 1 facets before."""
    occ, rx, ref, R_t, R_r, ks = (ctx[k] for k in ("occ", "rx", "ref", "R_t", "R_r", "ks"))
    near_field, eps, refl = ctx["near_field"], ctx["eps"], ctx["refl"]
    L = b - 1                                              # index of the radiating hit
    mg, nL, pL = r["mg"], r["n"][:, L], r["p"][:, L]
    # toward the receiver
    s_hat = normalize(rx[mg] - pL) if near_field else normalize(rx[mg] - ref)
    ok = _dot(nL, s_hat) > 0
    o = pL + eps * nL
    ok &= occ.unoccluded(o, rx[mg] - o, tfar=1.0 - 1e-7) if near_field else occ.unoccluded(o, s_hat)
    sel = np.nonzero(ok)[0]
    if len(sel) == 0:
        return
    r = {k: v[sel] for k, v in r.items()}
    mg, d, s_hat = r["mg"], r["d"], s_hat[sel]
    f, n, p, t, dirs = r["f"][:, :b], r["n"][:, :b], r["p"][:, :b], r["t"][:, :b], r["dirs"][:, :b]
    nL, pL, dL = n[:, L], p[:, L], dirs[:, L]
    path = t.sum(axis=1)
    if near_field:
        dist_r = np.linalg.norm(rx[mg] - pL, axis=1)
        phase_len = -(path + dist_r - R_t[mg] - R_r[mg])
        amp = (R_t[mg] / path) * (R_r[mg] / dist_r)        # image source of the b - 1 reflections
        scale = (path / r["rho"])[:, None]
    else:
        phase_len = -(_dot(d, p[:, 0] - ref) + t[:, 1:].sum(axis=1) - _dot(s_hat, pL - ref))
        amp = np.ones(len(mg))
        scale = 1.0
    # tube footprint on the last facet: mirror at the facets before, project along the ray onto its plane
    a_vec, b_vec = r["su"] * scale, r["sv"] * scale
    for j in range(L):
        a_vec, b_vec = _mirror(a_vec, n[:, j]), _mirror(b_vec, n[:, j])
    den = _dot(dL, nL)
    a_vec = a_vec - (_dot(a_vec, nL) / den)[:, None] * dL
    b_vec = b_vec - (_dot(b_vec, nL) / den)[:, None] * dL
    area = np.linalg.norm(np.cross(a_vec, b_vec), axis=1)
    w = s_hat - dL
    wa, wb = _dot(w, a_vec), _dot(w, b_vec)
    # fields: the incident E split into TE / TM parts at each GO bounce, 2^(b-1) real vectors, each
    # labelled by its modes (0 = TE, 1 = TM) and later weighted by the product of those coefficients
    terms = [((), antenna_polarisation(d, ctx["pol_t"]))]
    for j in range(L):
        terms = [(modes + (i,), part) for modes, e in terms
                 for i, part in enumerate(reflect_field_basis(n[:, j], dirs[:, j], e)[1])]
    p_hat = antenna_polarisation(-s_hat, ctx["pol_r"])
    coefs = [(modes, po_coefficients(nL, dL, s_hat, e, p_hat)) for modes, e in terms]   # (P, 3) each
    cos_abs = np.abs(np.einsum("pbi,pbi->pb", dirs, n))     # (P, b) at each hit

    def kernel(kidx):
        k = ks[kidx][None, :]
        foot = sinc_u(0.5 * k * wa[:, None]) * sinc_u(0.5 * k * wb[:, None])
        go = [_go_te_tm(refl, kidx, f[:, j], cos_abs[:, j]) for j in range(L)]
        if refl.material_mode:
            r_te, r_tm = refl.te_tm(kidx, f[:, L], cos_abs[:, L])

            def last(c):
                return c[:, 0:1] + r_te * c[:, 1:2] + r_tm * c[:, 2:3]
        else:   # the perfect-conductor currents scaled by -Gamma
            g = -refl.scalar(kidx, f[:, L])

            def last(c):
                return g * (c[:, 0:1] - c[:, 1:2] + c[:, 2:3])
        fac = 0.0
        for modes, c in coefs:
            weight = 1.0
            for j, i in enumerate(modes):
                weight = weight * go[j][i]
            fac = fac + weight * last(c)
        return foot * fac

    base = amp * area
    if ctx["amplitude_weight"] is not None:
        base = base * np.asarray(ctx["amplitude_weight"](mg, d, -s_hat))
    _sum_into(out, mg, ks, ctx["chunk_elements"], kernel, phase_len, base)
