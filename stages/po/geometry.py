"""Geometry kernels of the PO solver: the closed-form triangle phase integral, facet tables, and a few meshes with known RCS (plate, dihedral, sphere) for tests and benchmarks.

Everything here is numpy float64; shapes in the docstrings, SI units.
"""
from __future__ import annotations

import math

import numpy as np

# spread (radians) below which the triangle integral uses its Taylor series instead of the
# divided-difference formula; below it the series (10 terms) is exact to ~1e-15, above it the
# formula loses at most ~1e-16 / spread
_SERIES_SPREAD = 0.1
_SERIES_TERMS = 10
_INV_FACT = np.array([1.0 / math.factorial(n + 2) for n in range(_SERIES_TERMS)])


def _sincos(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sin x, cos x) of a float64 array; torch's vectorised kernels are ~4x faster than numpy's."""
    try:
        import torch
    except ImportError:  # pragma: no cover - torch is a dependency of rfir
        return np.sin(x), np.cos(x)
    t = torch.from_numpy(np.ascontiguousarray(x, dtype=np.float64))
    return torch.sin(t).numpy(), torch.cos(t).numpy()


def sinc_u(x):
    """sin(x) / x, 1 at 0 (unnormalised sinc)."""
    return np.sinc(np.asarray(x) / np.pi)


def triangle_phase_factor(alpha: np.ndarray, k: np.ndarray, phase_len: np.ndarray | None = None) -> np.ndarray:
    """(1/A) * integral over a flat triangle of exp(j k q . r') dS', for many triangles and wavenumbers.

    alpha: (P, 3) the projections q . (v_i - c) of the three vertices on the phase-gradient vector q
        (a length; c is any reference point, the returned value is relative to it);
    k: (K,) wavenumbers [rad/m]; phase_len: optional (P,) extra path length, the result is
        multiplied by exp(j k phase_len) (saves a separate complex exponential).
    Returns (P, K) complex; 1 when q is normal to the facet (and phase_len is None).

    Closed form: with x_i = j k alpha_i the integral over the triangle of area A is
    2 A exp[x0, x1, x2], the second divided difference of exp (Hermite-Genocchi). With the
    alphas sorted, exp[x0,x1,x2] = (exp[x1,x2] - exp[x0,x1]) / (x2 - x0), and each first
    divided difference is exp(mid) sinc(half gap), so the only division is by the largest gap
    (no cancellation when two vertices share a phase: the 'near-zero edge' case). When the
    whole spread k (alpha2 - alpha0) is below 0.1 rad (q nearly along the normal, or a small
    facet) the Taylor series sum_n h_n(y) / (n+2)! of the centred phases y is used; h_n are
    the complete homogeneous symmetric polynomials, from h_n = -e2 h_{n-2} + e3 h_{n-3}
    (e1 = 0 after centring). Both branches agree to ~1e-15 at the switch: results are smooth.
    """
    a = np.sort(np.asarray(alpha, dtype=float), axis=1)
    kk = np.asarray(k, dtype=float)[None, :]
    a0, a1, a2 = a[:, 0:1], a[:, 1:2], a[:, 2:3]
    d01, d12 = a1 - a0, a2 - a1
    extra = 0.0 if phase_len is None else np.asarray(phase_len, float)[:, None]
    spread = kk * (d01 + d12)  # (P, K) >= 0
    small = spread < _SERIES_SPREAD
    nsmall = int(small.sum())
    if nsmall < small.size:
        # exp(j t12) sinc(t12) - exp(-j t01) sinc(t01), in real arithmetic
        t01 = kk * (0.5 * d01)
        t12 = kk * (0.5 * d12)
        s01, c01 = _sincos(t01)
        s12, c12 = _sincos(t12)
        with np.errstate(divide="ignore", invalid="ignore"):
            q01 = np.where(t01 > 1e-8, s01 / t01, 1.0)
            q12 = np.where(t12 > 1e-8, s12 / t12, 1.0)
            inv = 2.0 / np.where(small, 1.0, spread)
        re = q12 * c12 - q01 * c01
        im = q12 * s12 + q01 * s01
        # 2 exp(j k (a1 + extra)) (re + j im) / (j spread)
        ph = kk * (a1 + extra)
        sp, cp = _sincos(ph)
        out = np.empty(spread.shape, dtype=complex)
        out.real = (cp * im + sp * re) * inv
        out.imag = (sp * im - cp * re) * inv
    else:
        out = np.empty(spread.shape, dtype=complex)
    if nsmall:
        mean = (a0 + a1 + a2) / 3.0
        b0, b1, b2 = kk * (a0 - mean), kk * (a1 - mean), kk * (a2 - mean)
        if nsmall < small.size:
            idx = np.nonzero(small)
            b0, b1, b2 = (np.broadcast_to(x, small.shape)[idx] for x in (b0, b1, b2))
            ph = np.broadcast_to(kk * (mean + extra), small.shape)[idx]
        else:
            ph = kk * (mean + extra)
        e2 = b0 * b1 + b0 * b2 + b1 * b2
        e3 = b0 * b1 * b2
        h = [np.ones_like(e2), np.zeros_like(e2), -e2]
        for n in range(3, _SERIES_TERMS):
            h.append(-e2 * h[n - 2] + e3 * h[n - 3])
        # h_n(j b) = j^n h_n(b)
        re = sum(((-1) ** (n // 2)) * h[n] * _INV_FACT[n] for n in range(0, _SERIES_TERMS, 2))
        im = sum(((-1) ** (n // 2)) * h[n] * _INV_FACT[n] for n in range(1, _SERIES_TERMS, 2))
        val = 2.0 * np.exp(1j * ph) * (re + 1j * im)
        if nsmall < small.size:
            out[idx] = val
        else:
            out = val
    return out


def facet_table(vertices: np.ndarray, faces: np.ndarray) -> dict:
    """Per-facet corners v0, v1, v2 (F,3), centroid c, unit normal n (from the winding), area A."""
    v = np.asarray(vertices, dtype=float)
    f = np.asarray(faces, dtype=np.int64)
    v0, v1, v2 = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    cr = np.cross(v1 - v0, v2 - v0)
    twice = np.linalg.norm(cr, axis=1)
    n = np.zeros_like(cr)
    ok = twice > 0
    n[ok] = cr[ok] / twice[ok, None]
    return {"v0": v0, "v1": v1, "v2": v2, "c": (v0 + v1 + v2) / 3.0, "n": n, "area": 0.5 * twice}


def normalize(x: np.ndarray, eps: float = 1e-300) -> np.ndarray:
    return x / np.maximum(np.linalg.norm(x, axis=-1, keepdims=True), eps)


# ----------------------------------------------------------------------------------------------
# meshes with closed-form RCS
# ----------------------------------------------------------------------------------------------
def plate_mesh(size_x: float, size_y: float | None = None, n: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Flat rectangular plate in the z = 0 plane, centred on the origin, normal +z, 2 n^2 triangles."""
    size_y = size_x if size_y is None else size_y
    xs = np.linspace(-size_x / 2, size_x / 2, n + 1)
    ys = np.linspace(-size_y / 2, size_y / 2, n + 1)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    v = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], 1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    f = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return v, f.astype(np.int64)


def dihedral_mesh(a: float, b: float, n: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """90-degree dihedral corner reflector: two plates a (along the fold, y) x b (width), fold on
    the y axis, plates in the planes x = 0 and z = 0, opening toward +x +z.

    Plate 1: x = 0, 0 <= z <= b, normal +x. Plate 2: z = 0, 0 <= x <= b, normal +z.
    The monostatic peak 8 pi a^2 b^2 / lambda^2 is on the bisector direction (1, 0, 1)/sqrt(2)
    (and, to first order, for any direction in the x-z plane between the plates).
    """
    v, f = plate_mesh(b, a, n)  # x in [-b/2, b/2], y in [-a/2, a/2], z = 0, normal +z
    v2 = v.copy()
    v2[:, 0] += b / 2  # plate 2: x in [0, b]
    v1 = np.stack([np.zeros(len(v)), v[:, 1], v[:, 0] + b / 2], 1)  # plate 1: x = 0, z in [0, b]
    f1 = f[:, [0, 2, 1]]  # (x,y)->(z,y) mapping flips orientation; normal -> +x
    verts = np.concatenate([v1, v2])
    faces = np.concatenate([f1, f + len(v)])
    return verts, faces


def trihedral_mesh(a: float, n: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Square trihedral corner reflector: three a x a plates in the planes z = 0, x = 0 and y = 0, each
    covering [0, a]^2 of its two coordinates, opening toward +x +y +z; 6 n^2 triangles (plates not merged).

    Normals +z, +x, +y (into the opening). The monostatic peak 12 pi a^4 / lambda^2 is on the symmetry
    axis (1, 1, 1)/sqrt(3): a triple bounce, one reflection off each plate.
    """
    v, f = plate_mesh(a, a, n)                      # (u, v, 0) with u, v in [-a/2, a/2], normal +z
    u, w = v[:, 0] + a / 2, v[:, 1] + a / 2
    z = np.zeros(len(v))
    # cyclic permutations of (u, w, 0) keep e_u x e_w along the plate's +normal: one face order for all three
    plates = [np.stack([u, w, z], 1), np.stack([z, u, w], 1), np.stack([w, z, u], 1)]
    return np.concatenate(plates), np.concatenate([f + i * len(v) for i in range(3)])


def icosphere(radius: float, subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """Geodesic sphere (20 * 4^subdivisions outward-wound triangles), vertices on the sphere."""
    t = (1.0 + 5.0**0.5) / 2.0
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t],
                  [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                  [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
                  [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], np.int64)
    v = normalize(v)
    for _ in range(subdivisions):
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        uniq, inv = np.unique(edges, axis=0, return_inverse=True)
        mids = normalize(0.5 * (v[uniq[:, 0]] + v[uniq[:, 1]]))
        m = inv.reshape(3, -1) + len(v)
        a, b, c = f[:, 0], f[:, 1], f[:, 2]
        ab, bc, ca = m[0], m[1], m[2]
        f = np.concatenate([np.stack([a, ab, ca], 1), np.stack([b, bc, ab], 1), np.stack([c, ca, bc], 1),
                            np.stack([ab, bc, ca], 1)])
        v = np.concatenate([v, mids])
    # outward winding check
    tab = facet_table(v, f)
    flip = np.einsum("ij,ij->i", tab["n"], tab["c"]) < 0
    f[flip] = f[flip][:, [0, 2, 1]]
    return v * radius, f


def subdivide_facets(v0: np.ndarray, v1: np.ndarray, v2: np.ndarray, max_edge_m: float):
    """Split every triangle whose longest edge exceeds max_edge_m into n^2 congruent triangles
    (n = ceil(longest / max_edge_m), barycentric grid). Returns (v0, v1, v2, parent): corners of
    the new triangles and the index of the triangle each came from. Flat: the surface, its
    normals and its area are unchanged; used to keep the near-field phase linear per facet."""
    edges = np.stack([np.linalg.norm(v1 - v0, axis=1), np.linalg.norm(v2 - v1, axis=1),
                      np.linalg.norm(v0 - v2, axis=1)], 1).max(1)
    n_split = np.maximum(1, np.ceil(edges / max_edge_m - 1e-9)).astype(np.int64)
    out0, out1, out2, par = [], [], [], []
    for n in np.unique(n_split):
        idx = np.nonzero(n_split == n)[0]
        if n == 1:
            out0.append(v0[idx]), out1.append(v1[idx]), out2.append(v2[idx]), par.append(idx)
            continue
        tri = []  # barycentric (a, b) of the three corners (weights of v1 and v2)
        for i in range(n):
            for j in range(n - i):
                tri.append(((i, j), (i + 1, j), (i, j + 1)))
                if i + j < n - 1:
                    tri.append(((i + 1, j), (i + 1, j + 1), (i, j + 1)))
        bc = np.asarray(tri, float) / n  # (T, 3 corners, 2)
        e1 = (v1[idx] - v0[idx])[:, None, None, :]
        e2 = (v2[idx] - v0[idx])[:, None, None, :]
        pts = v0[idx][:, None, None, :] + bc[None, :, :, 0:1] * e1 + bc[None, :, :, 1:2] * e2  # (I,T,3,3)
        out0.append(pts[:, :, 0].reshape(-1, 3))
        out1.append(pts[:, :, 1].reshape(-1, 3))
        out2.append(pts[:, :, 2].reshape(-1, 3))
        par.append(np.repeat(idx, len(tri)))
    return np.concatenate(out0), np.concatenate(out1), np.concatenate(out2), np.concatenate(par)
