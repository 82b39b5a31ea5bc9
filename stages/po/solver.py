"""Coherent physical-optics (PO) scattering from triangle meshes: monostatic and bistatic RCS.

Normalisation (exactly what `po_scattered_field` returns)
----------------------------------------------------------
The returned complex amplitude `s` [m] is the square root of an RCS with a phase:

    s = sqrt(4 pi) * R_r * exp(+j k (R_t + R_r)) * (E_s(rx) . p_r) / E_0

- `R_t = |tx - ref|`, `R_r = |rx - ref|`, `ref` = `ref_point` (default the origin);
- `E_0` is the incident field strength at `ref` (its phase there is `exp(-j k R_t)`);
- `p_r` is the receive polarisation unit vector, `E_s(rx)` the PO scattered field at the receiver.
- far field (`near_field=False`): plane wave from the direction of tx (seen from `ref`),
  observation toward the direction of rx, phases referred to `ref`; then `|s|^2` is the
  textbook far-field RCS `sigma = 4 pi r^2 |E_s|^2 / |E_0|^2` (r -> infinity).
- near field (`near_field=True`): each facet sees a spherical wave from tx,
  `E_0 R_t exp(-j k |tx - p|) / |tx - p|`, and radiates a spherical wave to rx, with phase and
  1/distance per facet (the phase is linearised across each facet about its centroid: the facet
  must be small against sqrt(lambda * range)). `|s|^2` is then the RCS a radar at that range
  would report with the radar equation using the ranges R_t, R_r to `ref`.

Conversions: `sigma = |s|^2` (m^2, `po_rcs`); the isotropic-antenna channel (P_T = 1 W, Friis
normalisation, `h_LoS = lambda exp(-j k d) / (4 pi d)`) is
`h = lambda * s * exp(-j k (R_t + R_r)) / ((4 pi)^1.5 R_t R_r)` (`channel_from_amplitude`), so
`|h|^2 = lambda^2 sigma / ((4 pi)^3 R_t^2 R_r^2)` (docs/physics.md section 5.2); multiply by
sqrt(G_T G_R) of the antenna pattern for horns.

Physics (first order)
---------------------
A facet is lit when it faces tx and rx from the same side (two-sided facets by default) and its
sample points (centroid, or centroid + 3 inner points) see tx and rx: Open3D ray casts, not
the normal's sign alone. The lit fraction weights the facet. On a lit facet the PO surface
currents are `J = n x H_tot`, `M = -n x E_tot`, with the reflected field from the facet's
reflection coefficients (TE/TM Fresnel of its material when materials are named; a perfect
conductor gives `J = 2 n x H_i`, `M = 0`). The far-zone field of a flat facet with a linear
phase is `E_s = j k exp(-j k r) / (4 pi r) * s_hat x (eta s_hat x J + M) * A * T(q)` where
`T` is the closed-form triangle integral (`geometry.triangle_phase_factor`).
With a scalar `face_reflection` Gamma the perfect-conductor currents are scaled by `-Gamma`
(Gamma = -1 is a perfect conductor; polarisation- and angle-independent; exact at normal
incidence, where the TE/TM model gives the same).
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from .currents import _dot, _sum_into, po_coefficients
from rfir_core.physics.polarisation import antenna_polarisation
from rfir_core.threads import single_thread_torch

from .geometry import facet_table, subdivide_facets, triangle_phase_factor
from .multi_bounce import multi_bounce
from .facet_materials import C0, permittivity_array
from .visibility import Occluder

_REFINE_BLOCK = 1 << 18  # sub-triangles per shadow-refinement block (bounds memory)


# ----------------------------------------------------------------------------------------------
# reflection models
# ----------------------------------------------------------------------------------------------
class _Reflection:
    """Per-facet reflection: material names (TE/TM Fresnel) or scalar Gamma (array or callable)."""

    def __init__(self, face_reflection, num_faces: int, freqs: np.ndarray, thickness):
        self.freqs = freqs
        self.callable = None
        self.const = None
        self.names = None
        fr = face_reflection
        if isinstance(fr, str) or (isinstance(fr, (np.ndarray, list, tuple)) and len(fr) and
                                   isinstance(np.asarray(fr).ravel()[0], (str, np.str_))):
            names = np.broadcast_to(np.asarray(fr, dtype=str), (num_faces,))
            uniq, inv = np.unique(names, return_inverse=True)
            self.names = uniq
            self.mat_idx = inv.astype(np.int64)
            # (K, n_materials) complex permittivity: geometry-free, reused by every facet
            self.eta = np.stack([permittivity_array(u, freqs) for u in uniq], axis=1)
            th = None if thickness is None else np.broadcast_to(np.asarray(thickness, float), (num_faces,))
            self.thickness = th
            self.ks = 2.0 * np.pi * freqs / C0
            self.is_pec = ~np.all(np.isfinite(self.eta), axis=0)
            self.any_pec = bool(self.is_pec.any())
            self.eta_finite = np.where(np.isfinite(self.eta), self.eta, 4.0 + 0j)
            self.root0 = np.sqrt(self.eta_finite)
            self.conductor = np.abs(self.eta_finite).min(axis=0) > 1e6
            if th is not None:
                # a slab whose two-way attenuation leaves < 1e-15 of the back-face echo at every
                # frequency and angle (metal: skin depth ~ um) reflects like a half-space: skip it
                k = self.ks[:, None]
                worst = np.full(len(uniq), -np.inf)
                for s2 in (0.0, 1.0):
                    im = np.sqrt(self.eta_finite - s2).imag  # <= 0
                    worst = np.maximum(worst, (2.0 * k * im).max(axis=0))  # log|e^{-j2q}| per unit thickness
                self.thickness = np.where(worst[self.mat_idx] * th < np.log(1e-15), 0.0, th)
        elif callable(fr):
            self.callable = fr
            self._cache = {}
        else:
            self.const = np.broadcast_to(np.asarray(fr, dtype=complex), (num_faces,)).copy()

    @property
    def material_mode(self) -> bool:
        return self.names is not None

    def scalar(self, kidx: np.ndarray, fidx: np.ndarray) -> np.ndarray:
        """(P, len(kidx)) scalar Gamma per (facet, frequency)."""
        if self.const is not None:
            return self.const[fidx][:, None]
        cols = []
        for ki in kidx:
            g = self._cache.get(int(ki))
            if g is None:
                g = np.asarray(self.callable(float(self.freqs[ki])), dtype=complex)
                if len(self._cache) < 64:  # bounded: wideband sweeps recompute
                    self._cache[int(ki)] = g
            cols.append(np.full(len(fidx), complex(g)) if g.ndim == 0 else g[fidx])
        return np.stack(cols, axis=1)

    def te_tm(self, kidx: np.ndarray, fidx: np.ndarray, cos_theta: np.ndarray):
        """(R_TE, R_TM), each (P, len(kidx)), for facets fidx at incidence cos_theta (P,).

        The same formulas as materials.fresnel, written lean for the hot loop."""
        mat = self.mat_idx[fidx]
        eta = self.eta_finite[kidx][:, mat].T  # (P, Kc)
        c = np.clip(cos_theta, 1e-12, 1.0)[:, None]
        # good conductors (|eta| > 1e6, e.g. ITU metal ~ 1e7): sqrt(eta - sin^2) = sqrt(eta) to 1e-7
        root = self.root0[kidx][:, mat].T
        lossy = ~self.conductor[mat]
        if lossy.any():
            root[lossy] = np.sqrt(eta[lossy] - (1.0 - c[lossy] * c[lossy]))
        r_te = (c - root) / (c + root)
        ec = eta * c
        r_tm = (ec - root) / (ec + root)
        if self.thickness is not None:
            th = self.thickness[fidx]
            slab = th > 0  # thickness 0 = half-space
            if slab.any():
                q2 = (2.0 * self.ks[kidx])[None, :] * th[slab][:, None] * root[slab]
                ph = np.exp(np.maximum((-1j * q2).real, -700.0) + 1j * (-1j * q2).imag)
                a, b = r_te[slab], r_tm[slab]
                r_te[slab] = a * (1.0 - ph) / (1.0 - a * a * ph)
                r_tm[slab] = b * (1.0 - ph) / (1.0 - b * b * ph)
        if self.any_pec:
            rows = self.is_pec[mat]
            if rows.any():
                r_te[rows] = -1.0
                r_tm[rows] = 1.0
        return r_te, r_tm

    def factor(self, coef: np.ndarray, kidx, fidx, cos_theta) -> np.ndarray:
        """Combine PO coefficients (P,3) = (c0, c_TE, c_TM) with the facet's reflection -> (P, Kc)."""
        if self.material_mode:
            r_te, r_tm = self.te_tm(kidx, fidx, cos_theta)
            return coef[:, 0:1] + r_te * coef[:, 1:2] + r_tm * coef[:, 2:3]
        pec = coef[:, 0] - coef[:, 1] + coef[:, 2]
        return -self.scalar(kidx, fidx) * pec[:, None]


# ----------------------------------------------------------------------------------------------
# main entry points
# ----------------------------------------------------------------------------------------------
def _parse_pol(polarization):
    if isinstance(polarization, str):
        p = polarization.upper()
        if len(p) == 2 and p[0] in "VH" and p[1] in "VH":
            return p[0], p[1]
        return p, p
    t, r = polarization
    return str(t).upper(), str(r).upper()


def po_scattered_field(vertices, faces, face_reflection, tx_pos, rx_pos, freqs_hz, *,
                       polarization="V", second_order: bool = False, max_bounces: int = 2, near_field: bool = False,
                       ref_point=(0.0, 0.0, 0.0), face_thickness=None, two_sided: bool = True,
                       shadow_samples: int = 4, chunk_facets: int = 8192, chunk_elements: int = 1 << 19,
                       sbr_spacing_m: float | None = None, occluder: Occluder | None = None,
                       amplitude_weight: Callable | None = None, max_facet_edge_m: float | None = None,
                       shadow_refine_m: float | None = None,
                       progress: Callable[[int, int], None] | None = None) -> np.ndarray:
    """Complex PO scattering amplitude s [m], shape (M, K); sigma = |s|^2 (see module docstring).

    vertices (V,3) m, faces (F,3) int (winding gives the outward normal; used only when
    two_sided=False), face_reflection: scalar/(F,) complex Gamma (-1 = perfect conductor), a
    callable freq_hz -> (F,) complex Gamma, or a material name / (F,) array of names (ITU-R
    P.2040 + "pec", angle- and polarisation-dependent TE/TM Fresnel; face_thickness (F,) or
    scalar in m makes them slabs as in Sionna). tx_pos, rx_pos (M,3) m: one radar geometry per
    row (monostatic when equal). freqs_hz (K,). polarization "V", "H", "VH" (tx V, rx H) or a
    (tx, rx) pair. second_order adds the paths over 2 to max_bounces facets (ray tubes, GO then PO,
    see `multi_bounce.py`): max_bounces = 2 the double bounce (a dihedral's flash), 3 also the triple
    bounce (a trihedral's flash); ignored when second_order is False.
    shadow_samples 1 (centroid) or 4 (centroid + 3 inner points) ray casts per facet and end.
    chunk_facets bounds the (facet, aspect) pairs processed at once and chunk_elements the
    pairs x frequencies block, so memory stays bounded for any M, F, K.
    amplitude_weight(aspect_index (P,), u_tx (P,3), u_rx (P,3)) -> (P,) multiplies each facet's
    (and each multiple-bounce tube's) contribution; u_tx / u_rx are unit vectors from the Tx / Rx
    toward the scattering point. Use it for antenna patterns, sqrt(G_T(u_tx) G_R(u_rx)): then
    |s|^2 = sigma * G_T * G_R for a small object, and channel_from_amplitude gives the channel
    with the patterns included. None = isotropic (s is the bare RCS amplitude).
    max_facet_edge_m: facets longer than this are split (flat, n^2 congruent parts) before the
    PO sum. None = automatic: lambda_min (so the shadow samples resolve shadow boundaries to about
    a wavelength; the far-field facet integral itself is exact for any size) and, in the
    near-field mode, where the phase is linearised per facet, also L <= sqrt(0.4 R / k) (two-way
    quadratic phase error k L^2 / (4 R) <= 0.1 rad at the closest range R and highest k, but
    at least lambda_min / 4). 0 disables.
    shadow_refine_m: partly lit facets (some but not all of the shadow samples lit) are split into
    sub-triangles of this size, each lit or not by its own ray cast (default lambda_min / 4; 0 =
    weight the whole facet by its lit fraction instead).
    occluder: a prebuilt Occluder (e.g. the same mesh plus a room) to reuse across calls.
    progress(done_aspects, total_aspects) is called after every aspect chunk.
    """
    with single_thread_torch():
        return _po_scattered_field(vertices, faces, face_reflection, tx_pos, rx_pos, freqs_hz, polarization,
                                   second_order, max_bounces, near_field, ref_point, face_thickness, two_sided, shadow_samples,
                                   chunk_facets, chunk_elements, sbr_spacing_m, occluder, amplitude_weight,
                                   max_facet_edge_m, shadow_refine_m, progress)


def _po_scattered_field(vertices, faces, face_reflection, tx_pos, rx_pos, freqs_hz, polarization, second_order,
                        max_bounces, near_field, ref_point, face_thickness, two_sided, shadow_samples, chunk_facets,
                        chunk_elements, sbr_spacing_m, occluder, amplitude_weight, max_facet_edge_m,
                        shadow_refine_m, progress):
    verts = np.asarray(vertices, dtype=float)
    fcs = np.asarray(faces, dtype=np.int64)
    tx = np.atleast_2d(np.asarray(tx_pos, dtype=float))
    rx = np.atleast_2d(np.asarray(rx_pos, dtype=float))
    if tx.shape != rx.shape:
        raise ValueError(f"tx_pos {tx.shape} and rx_pos {rx.shape} must have the same shape (M, 3)")
    freqs = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
    ks = 2.0 * np.pi * freqs / C0
    ref = np.asarray(ref_point, dtype=float)
    M, K, F = len(tx), len(freqs), len(fcs)
    out = np.zeros((M, K), dtype=complex)
    if F == 0 or M == 0:
        return out
    pol_t, pol_r = _parse_pol(polarization)
    refl = _Reflection(face_reflection, F, freqs, face_thickness)
    occ = occluder if occluder is not None else Occluder(verts, fcs)
    tab0 = facet_table(verts, fcs)
    tab, parent = _split_table(tab0, verts, tx, rx, ref, ks, near_field, max_facet_edge_m)
    good = np.nonzero(tab["area"] > 0)[0]
    c_all, n_all = tab["c"], tab["n"]
    rel = np.stack([tab["v0"] - c_all, tab["v1"] - c_all, tab["v2"] - c_all], axis=1)  # (F,3,3)
    eps = 1e-6 * max(occ.size, 1e-3)
    if shadow_samples == 1:
        samples = c_all[:, None, :]
    elif shadow_samples == 4:
        samples = np.concatenate([c_all[:, None, :], c_all[:, None, :] + 0.5 * rel], axis=1)
    else:
        raise ValueError("shadow_samples must be 1 or 4")
    S = samples.shape[1]

    dt_far = tx - ref
    R_t = np.linalg.norm(dt_far, axis=1)
    dr_far = rx - ref
    R_r = np.linalg.norm(dr_far, axis=1)
    if np.any(R_t <= 0) or np.any(R_r <= 0):
        raise ValueError("tx and rx must not sit on ref_point")
    t_hat, r_hat_far = dt_far / R_t[:, None], dr_far / R_r[:, None]
    mono = np.all(np.abs(tx - rx) <= 1e-12 * (1 + np.abs(tx)), axis=1)

    refine_edge = 0.25 * 2.0 * np.pi / float(ks.max()) if shadow_refine_m is None else float(shadow_refine_m)
    Fg = len(good)
    m_chunk = max(1, min(M, (1 << 19) // max(1, Fg * S)))  # <= 2^19 shadow rays per aspect block
    pair_chunk = max(256, int(chunk_facets))
    done = 0
    for m0 in range(0, M, m_chunk):
        ms = np.arange(m0, min(M, m0 + m_chunk))
        # ---- candidate (aspect, facet) pairs: tx and rx on the same side of the facet ----
        if near_field:
            to_t = tx[ms][:, None, :] - c_all[good][None]
            to_r = rx[ms][:, None, :] - c_all[good][None]
            nt = np.einsum("mfi,fi->mf", to_t, n_all[good])
            nr = np.einsum("mfi,fi->mf", to_r, n_all[good])
        else:
            nt = t_hat[ms] @ n_all[good].T
            nr = r_hat_far[ms] @ n_all[good].T
        cand = (nt * nr > 0) & ((nt > 0) | two_sided)
        mi, fj = np.nonzero(cand)
        fi = good[fj]
        mg = ms[mi]
        if len(mi) == 0:
            done += len(ms)
            if progress:
                progress(done, M)
            continue
        sgn = np.sign(nt[mi, fj])
        nf = n_all[fi] * sgn[:, None]  # normal on the lit side
        # ---- ray-cast lit fraction ----
        orig = samples[fi] + eps * nf[:, None, :]  # (P,S,3)
        vis = _visible(occ, orig, tx[mg], near_field, t_hat[mg])
        need_r = ~mono[mg]
        if need_r.any():
            vr = _visible(occ, orig[need_r], rx[mg[need_r]], near_field, r_hat_far[mg[need_r]])
            vis[need_r] &= vr
        w = vis.mean(axis=1)
        full = w >= 1.0
        part = (w > 0) & ~full
        blocks = [{"mg": mg[full], "ri": parent[fi[full]], "nf": nf[full], "w": w[full], "c": c_all[fi[full]],
                   "rel": rel[fi[full]], "area": tab["area"][fi[full]]}]
        if part.any() and refine_edge <= 0:  # lit-fraction weighting only
            fp = fi[part]
            blocks.append({"mg": mg[part], "ri": parent[fp], "nf": nf[part], "w": w[part], "c": c_all[fp],
                           "rel": rel[fp], "area": tab["area"][fp]})
        # ---- PO sum over lit pairs, in chunks ----
        for pairs in blocks:
            _accumulate_pairs(out, pairs, pair_chunk, tx, rx, ref, R_t, R_r, t_hat, r_hat_far, near_field, pol_t,
                              pol_r, ks, refl, chunk_elements, amplitude_weight)
        if part.any() and refine_edge > 0:  # split partly lit facets, in blocks of <= ~2^18 parts
            ip = np.nonzero(part)[0]
            cost = np.cumsum(_refine_counts(tab, fi[ip], refine_edge))
            lo = 0
            while lo < len(ip):
                hi = max(lo + 1, int(np.searchsorted(cost, (cost[lo - 1] if lo else 0) + _REFINE_BLOCK, side="right")))
                sel = ip[lo:hi]
                sub = _refine_partial(occ, tab, fi[sel], mg[sel], nf[sel], tx, rx, t_hat, r_hat_far, mono,
                                      near_field, eps, refine_edge)
                sub["ri"] = parent[sub.pop("fi")]
                order = np.argsort(sub["mg"], kind="stable")
                _accumulate_pairs(out, {k: v[order] for k, v in sub.items()}, pair_chunk, tx, rx, ref, R_t, R_r,
                                  t_hat, r_hat_far, near_field, pol_t, pol_r, ks, refl, chunk_elements,
                                  amplitude_weight)
                lo = hi
        done += len(ms)
        if progress:
            progress(done, M)

    if second_order:
        out += multi_bounce(verts, fcs, tab0, refl, occ, tx, rx, ref, ks, pol_t, pol_r, max_bounces=max_bounces,
                            near_field=near_field, two_sided=two_sided, spacing_m=sbr_spacing_m,
                            chunk_elements=chunk_elements, amplitude_weight=amplitude_weight)
    return out


def _accumulate_pairs(out, pairs, pair_chunk, *args):
    for p0 in range(0, len(pairs["mg"]), pair_chunk):
        sl = slice(p0, p0 + pair_chunk)
        _accumulate_first_order(out, *(pairs[k][sl] for k in ("mg", "ri", "nf", "w", "c", "rel", "area")), *args)


def _refine_counts(tab, fi, edge):
    """Number of sub-triangles _refine_partial makes for each facet."""
    edges = np.stack([np.linalg.norm(tab["v1"][fi] - tab["v0"][fi], axis=1),
                      np.linalg.norm(tab["v2"][fi] - tab["v1"][fi], axis=1),
                      np.linalg.norm(tab["v0"][fi] - tab["v2"][fi], axis=1)], 1).max(1)
    n = np.minimum(32, np.maximum(1, np.ceil(edges / edge - 1e-9)))
    return (n * n).astype(np.int64)


def _refine_partial(occ, tab, fi, mg, nf, tx, rx, t_hat, r_hat_far, mono, near_field, eps, edge):
    """Split partly lit (aspect, facet) pairs into sub-triangles of longest edge <= edge (at most
    32 x 32 per facet), ray-cast each sub-centroid, and keep the lit ones as pairs of weight 1."""
    edges = np.stack([np.linalg.norm(tab["v1"][fi] - tab["v0"][fi], axis=1),
                      np.linalg.norm(tab["v2"][fi] - tab["v1"][fi], axis=1),
                      np.linalg.norm(tab["v0"][fi] - tab["v2"][fi], axis=1)], 1).max(1)
    eff = np.maximum(edge, edges / 32.0)  # cap the split at 32 x 32
    out = {k: [] for k in ("mg", "fi", "nf", "w", "c", "rel", "area")}
    for e_val in np.unique(np.ceil(edges / eff - 1e-9)):
        grp = np.nonzero(np.ceil(edges / eff - 1e-9) == e_val)[0]
        f = fi[grp]
        v0, v1, v2, par = subdivide_facets(tab["v0"][f], tab["v1"][f], tab["v2"][f], float(edges[grp].max() / e_val) * (1 + 1e-9))
        # subdivide_facets splits per facet by its own longest edge: recompute the owner pair
        g = grp[par]
        c = (v0 + v1 + v2) / 3.0
        o = c + eps * nf[g]
        vis = _visible(occ, o[:, None, :], tx[mg[g]], near_field, t_hat[mg[g]])[:, 0]
        need_r = ~mono[mg[g]]
        if need_r.any():
            vis[need_r] &= _visible(occ, o[need_r][:, None, :], rx[mg[g][need_r]], near_field,
                                    r_hat_far[mg[g][need_r]])[:, 0]
        k = np.nonzero(vis)[0]
        g, v0, v1, v2, c = g[k], v0[k], v1[k], v2[k], c[k]
        out["mg"].append(mg[g])
        out["fi"].append(fi[g])
        out["nf"].append(nf[g])
        out["w"].append(np.ones(len(g)))
        out["c"].append(c)
        out["rel"].append(np.stack([v0 - c, v1 - c, v2 - c], axis=1))
        out["area"].append(0.5 * np.linalg.norm(np.cross(v1 - v0, v2 - v0), axis=1))
    return {k: np.concatenate(v) if v else np.zeros((0,)) for k, v in out.items()}


def _split_table(tab, verts, tx, rx, ref, ks, near_field, max_edge):
    """Facet table after optional splitting, and the parent (original facet) of every entry."""
    F = len(tab["area"])
    if max_edge is None:
        k_max = float(np.max(ks))
        max_edge = 2.0 * np.pi / k_max  # lambda_min: shadow boundaries resolved to a wavelength
        if near_field:
            radius = float(np.linalg.norm(verts - ref, axis=1).max())
            r_min = float(min(np.linalg.norm(tx - ref, axis=1).min(), np.linalg.norm(rx - ref, axis=1).min()))
            r_close = max(r_min - radius, 0.25 * r_min, 1e-3)
            max_edge = min(max_edge, max(np.sqrt(0.4 * r_close / k_max), 0.25 * 2.0 * np.pi / k_max))
    if not max_edge or not np.isfinite(max_edge):
        return tab, np.arange(F)
    v0, v1, v2, parent = subdivide_facets(tab["v0"], tab["v1"], tab["v2"], float(max_edge))
    if len(parent) == F:
        return tab, np.arange(F)
    n = tab["n"][parent]
    area = 0.5 * np.linalg.norm(np.cross(v1 - v0, v2 - v0), axis=1)
    area[tab["area"][parent] <= 0] = 0.0
    return {"v0": v0, "v1": v1, "v2": v2, "c": (v0 + v1 + v2) / 3.0, "n": n, "area": area}, parent


def _visible(occ: Occluder, orig: np.ndarray, target: np.ndarray, near_field: bool, far_dir: np.ndarray):
    """orig (P,S,3); target (P,3) positions; far_dir (P,3) unit directions (far field). -> (P,S) bool."""
    P, S, _ = orig.shape
    o = orig.reshape(-1, 3)
    if near_field:
        d = (target[:, None, :] - orig).reshape(-1, 3)
        return occ.unoccluded(o, d, tfar=1.0 - 1e-7).reshape(P, S)
    d = np.repeat(far_dir, S, axis=0)
    return occ.unoccluded(o, d).reshape(P, S)


def _accumulate_first_order(out, mg, ri, nf, w, c, rel, area, tx, rx, ref, R_t, R_r, t_hat, r_hat_far,
                            near_field, pol_t, pol_r, ks, refl, chunk_elements, amplitude_weight=None):
    """Add the PO sum of lit pairs: aspect mg, reflection index ri (original facet), lit-side normal
    nf, weight w, centroid c (P,3), corners relative to c rel (P,3,3), area (P,)."""
    if near_field:
        vt = tx[mg] - c
        vr = rx[mg] - c
        dt = np.linalg.norm(vt, axis=1)
        dr = np.linalg.norm(vr, axis=1)
        i_hat = -vt / dt[:, None]
        s_hat = vr / dr[:, None]
        phase_len = -(dt + dr - R_t[mg] - R_r[mg])
        amp = (R_t[mg] * R_r[mg]) / (dt * dr)
    else:
        i_hat = -t_hat[mg]
        s_hat = r_hat_far[mg]
        phase_len = _dot(s_hat - i_hat, c - ref)
        amp = np.ones(len(mg))
    e_inc = antenna_polarisation(i_hat, pol_t)
    p_hat = antenna_polarisation(-s_hat, pol_r)
    coef = po_coefficients(nf, i_hat, s_hat, e_inc, p_hat)
    q = s_hat - i_hat
    alpha = np.einsum("pvi,pi->pv", rel, q)
    base = w * amp * area
    if amplitude_weight is not None:
        base = base * np.asarray(amplitude_weight(mg, i_hat, -s_hat))
    cos_t = np.abs(_dot(i_hat, nf))
    _sum_into(out, mg, ks, chunk_elements,
              lambda kidx: triangle_phase_factor(alpha, ks[kidx], phase_len) * refl.factor(coef, kidx, ri, cos_t),
              None, base)


def po_rcs(vertices, faces, face_reflection, tx_pos, rx_pos, freqs_hz, **kwargs) -> np.ndarray:
    """PO radar cross section sigma = |s|^2 [m^2], shape (M, K): monostatic where tx == rx,
    bistatic otherwise. Same arguments as `po_scattered_field`."""
    return np.abs(po_scattered_field(vertices, faces, face_reflection, tx_pos, rx_pos, freqs_hz, **kwargs)) ** 2


def channel_from_amplitude(s, freqs_hz, range_tx_m, range_rx_m) -> np.ndarray:
    """Isotropic-antenna channel h (P_R / P_T = |h|^2) from the PO amplitude s (M,K).

    h = lambda s exp(-j k (R_t + R_r)) / ((4 pi)^1.5 R_t R_r); range_* are (M,) distances to ref_point.
    """
    f = np.asarray(freqs_hz, float)[None, :]
    lam = C0 / f
    k = 2.0 * np.pi / lam
    rt = np.asarray(range_tx_m, float).reshape(-1, 1)
    rr = np.asarray(range_rx_m, float).reshape(-1, 1)
    return lam * np.asarray(s) * np.exp(-1j * k * (rt + rr)) / ((4.0 * np.pi) ** 1.5 * rt * rr)


def rcs_dbsm(sigma_m2) -> np.ndarray:
    """10 log10(sigma / 1 m^2), floored at -300 dBsm."""
    return 10.0 * np.log10(np.maximum(np.asarray(sigma_m2, float), 1e-30))


PO_METHOD = ("physical optics: ray-cast lit facets (Open3D), closed-form triangle integrals, TE/TM Fresnel "
             "(ITU-R P.2040) or scalar Gamma; optional multiple bounces up to max_bounces (SBR, GO then PO)")


def provenance(**po_kwargs) -> dict:
    """Provenance attributes for a data set made with po_scattered_field(**po_kwargs): the backend
    name, the method, and every solver setting (defaults filled in), JSON-friendly."""
    import inspect

    sig = inspect.signature(po_scattered_field)
    out = {"backend": "po", "method": PO_METHOD}
    skip = {"vertices", "faces", "face_reflection", "tx_pos", "rx_pos", "freqs_hz", "occluder", "progress",
            "amplitude_weight", "face_thickness"}
    for name, p in sig.parameters.items():
        if name in skip:
            continue
        val = po_kwargs.get(name, p.default)
        if isinstance(val, tuple):
            val = list(val)
        out[name] = val if isinstance(val, (bool, int, float, str, list, type(None))) else repr(val)
    out["amplitude_weight"] = "per-facet antenna pattern" if po_kwargs.get("amplitude_weight") else "none (isotropic)"
    return out
