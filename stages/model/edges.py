"""Edge waves: the fringe (PTD) field of the outer edges of planar patches (docs/physics.md section 8.13).

Physical optics (the surfel sum, physical.py) integrates the currents of an infinite plane over a
finite surface; the field of an edge is then only PO's truncation of that integral. The exact edge
field of a perfectly conducting wedge (Keller's GTD coefficient, exterior angle n pi) differs from
it by the fringe field of Ufimtsev's physical theory of diffraction, finite at every angle. Here it
is added as equivalent edge currents along each edge, integrated with the monostatic phase:

    S_edge = sum_(edge segments e) sqrt(G_T G_R) rho_e V_e [w_s f_s(phi, n) + w_h f_h(phi, n)]
             L_e sinc(k L_e s.t) exp(-2 j k d_e) / (8 pi k d_e^2)

- s: the unit vector from the segment's midpoint toward the radar, d_e its distance; t the edge's
  tangent, L_e the segment's length (the sinc is the exact integral of the phase along the segment);
- phi: the angle, in the plane across the edge, from the wedge's face 0 to the projection of s
  (0 <= phi <= n pi outside the wedge; inside it, the radar sees the solid or a concave corner,
  whose returns are the surfels' reflections and double bounces: no edge term);
- f_s, f_h: the fringe coefficients (`wedge_fringe`) for E along the edge (soft) and across it
  (hard), GTD backscatter minus the PO edge terms tan(phi) and tan(n pi - phi) of the lit faces:
      a_s = (2 sin(pi/n) / n) (T1 - T2),   a_h = -(2 sin(pi/n) / n) (T1 + T2),
      T1 = 1 / (cos(pi/n) - 1),   T2 = 1 / (cos(pi/n) - cos(2 phi / n));
  a half-plane (n = 2): f_s = sec phi - tan phi - 1, f_h = sec phi - tan phi + 1;
- w_s = (p . t_perp)^2, w_h = 1 - w_s: the share of the radar's polarisation p along the part of the
  edge across the ray (t_perp = t - (t.s) s, normalised); the 1 / sin^2(beta) of the equivalent
  currents cancels against their excitation and radiation (monostatic), so an oblique edge gets the
  coefficients of the plane across it (the backscatter form of Michaeli's fringe currents);
- rho_e = -R_TE(0) sqrt(1 - S^2) of the edge's material (mean of its two faces): 1 for a perfect
  conductor; a dielectric edge is scaled by its normal-incidence reflection coefficient (an
  approximation: the fringe coefficients of dielectric wedges are not those of a perfect conductor);
- V_e: lit when a surfel of either face next to the edge is lit from the radar (physical.py's V).

Waves across a sheet (`strip_double_diffraction`, `strip_return_diffraction`, `_double_terms`): for E across
a sheet's edges (the hard case) the field diffracted at one edge runs across the face, grazing, and is
diffracted again at the facing parallel edge (`Edges.opposite`, width w); in backscatter both paths (B -> A,
A -> B) have the same phase. Each is added as an item of segment A with the coefficient of the strip's GTD in
the plane across the edges (wavenumber k sin beta), the hard share w_h of the polarisation, the phase of the
path radar-B-A-radar and A's sinc; a soft field vanishes on the face (no such term). This is what sets a
plate's level in H polarisation at wide angles. The same item carries the return path radar-A-B-A-radar
(B sends the wave back along the face), and both carry the further round trips between the edges (a
geometric series). Near grazing beyond A these are as large as the first-order waves and cancel them: the
total field at the far edge (the plane wave and A's diffracted wave) vanishes as the radar reaches the
sheet's plane, and the hard sheet's echo falls as (cos theta)^4 as the exact one does.

Waves between an outer edge and a fold (`_fold_terms`, `wedge_grazing_vertex`): in the hard case the wave
diffracted at a half-plane edge O also runs along its face's outer side to a fold F straight across the face
(`Edges.fold`; a dihedral's fold seen from outside, n = 1.5) and is diffracted there back to the radar, and the
reverse; one item of O with one crossing (`_crossing`) and Keller's coefficients of the two wedges for a wave
grazing along their faces, the UTD transition function at the grazing wave's shadow boundary. A radar in the
fold's concave corner gets none; the return from the concave side (O -> corner -> O) is left out
(docs/physics.md section 8.13 says why).

Edges of a surfel set (`patch_edges`): for each planar patch (second_order.planar_patches), the level
line at half the patch's interior coverage C(x) (the sum of its Gaussians in its plane, which falls to
half its value at the border of a tiling; surfels.py), simplified to straight pieces and cut into
segments no longer than a surfel. An outer edge of one patch that lies on an outer edge of another
(a fold, a box's edge, the two faces of a thin sheet) is one wedge, kept once, with the two faces'
directions; the exterior angle follows from them (n = 2: a half-plane; n -> 1: a flat continuation,
no fringe).

Built for co-located antennas (monostatic radar), as the double bounce; links with separate antennas
get no edge term.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from .antenna_patterns import AntennaPattern
from .occlusion import FrozenGeometry
from .link_set import LinkSet

from .link_rows import renumber_links
from rfir_core.physics.materials import C0, specular_share
from rfir_core.physics.polarisation import antenna_polarisation

WEDGE_T_COS = 0.9       # outer edges of two patches with tangents this parallel, on one line: one wedge
WEDGE_ACROSS_HALF = 1.0  # ... and at most this many surfel half-sides apart across their tangent (see patch_edges)
SINGULAR_RAD = 1e-3     # near a face's normal GTD and PO are singular: the fringe is averaged at +-this


@dataclass
class Edges:
    """Edge segments: mid [E, 3] m, tangent [E, 3] unit, length [E] m; face_a, face_b [E, 3]: unit vectors
    across the edge, from it into each face (equal for a half-plane); gauss_a, gauss_b [E]: a surfel of each
    face next to the edge (its material and visibility); opposite [E]: for a half-plane edge, the segment of
    the facing parallel half-plane edge of the same patch straight across it (-1: none), width [E] m the
    distance across (the doubly diffracted wave, `_double_terms`); span [E, 2] m: the extent of the straight
    run of the boundary the segment belongs to, along its tangent from its midpoint (lo <= 0 <= hi); fold [E]:
    for a half-plane edge, the segment of a fold (a wedge of two patches, 1 < n < 2) straight across its face,
    parallel, one of whose faces points back to it (-1: none), fold_width [E] m the distance across (the wave
    between an outer edge and a fold along the fold's outer face, `_fold_terms`)."""

    mid: torch.Tensor
    tangent: torch.Tensor
    length: torch.Tensor
    face_a: torch.Tensor
    face_b: torch.Tensor
    gauss_a: torch.Tensor
    gauss_b: torch.Tensor
    opposite: torch.Tensor
    width: torch.Tensor
    span: torch.Tensor
    fold: torch.Tensor
    fold_width: torch.Tensor

    @property
    def num(self) -> int:
        return int(self.length.numel())


def _empty_edges() -> Edges:
    z3 = torch.zeros((0, 3), dtype=torch.float64)
    zi = torch.zeros(0, dtype=torch.int64)
    z = torch.zeros(0, dtype=torch.float64)
    return Edges(z3, z3, z, z3, z3, zi, zi, zi, z, torch.zeros((0, 2), dtype=torch.float64), zi, z)


def _simplify(line: np.ndarray, tol: float) -> np.ndarray:
    """Douglas-Peucker: the vertices of polyline `line` [P, 2] that keep it within `tol` of the original."""
    keep = np.zeros(len(line), bool)
    keep[[0, -1]] = True
    stack = [(0, len(line) - 1)]
    while stack:
        a, b = stack.pop()
        if b <= a + 1:
            continue
        d = line[b] - line[a]
        nd = np.hypot(*d)
        rel = line[a + 1:b] - line[a]
        dist = np.abs(rel[:, 0] * d[1] - rel[:, 1] * d[0]) / nd if nd > 0 else np.hypot(rel[:, 0], rel[:, 1])
        i = int(np.argmax(dist))
        if dist[i] > tol:
            keep[a + 1 + i] = True
            stack += [(a, a + 1 + i), (a + 1 + i, b)]
    return line[keep]


def _coverage_2d(pts: np.ndarray, cov2: np.ndarray, x2: np.ndarray, reach: float) -> np.ndarray:
    """C(x) [Q] = sum_m exp(-0.5 (x - mu_m)^T S_m^-1 (x - mu_m)) at points x2 [Q, 2] of a patch's plane, over
    its members (means pts [G, 2], in-plane covariances cov2 [G, 2, 2]), each within `reach` of its mean."""
    from scipy.spatial import cKDTree

    inv = np.linalg.inv(cov2)
    near = cKDTree(pts).query_ball_point(x2, reach)
    counts = np.fromiter((len(n) for n in near), dtype=np.int64, count=len(near))
    if not counts.sum():
        return np.zeros(len(x2))
    member = np.concatenate([np.asarray(n, dtype=np.int64) for n in near if n])
    point = np.repeat(np.arange(len(x2)), counts)
    d = x2[point] - pts[member]
    val = np.exp(-0.5 * np.einsum("qa,qab,qb->q", d, inv[member], d))
    return np.bincount(point, weights=val, minlength=len(x2))


def _coverage_grid(pts: np.ndarray, cov2: np.ndarray, gx: np.ndarray, gy: np.ndarray, reach: float) -> np.ndarray:
    """C on the regular grid gx x gy [len(gy), len(gx)] (as _coverage_2d): each member adds its Gaussian
    to the grid points of a square window of half-width `reach` around its mean."""
    inv = np.linalg.inv(cov2)
    step = gx[1] - gx[0] if len(gx) > 1 else 1.0
    w = int(math.ceil(reach / step))
    off = np.arange(-w, w + 1)
    ix = np.rint((pts[:, 0] - gx[0]) / step).astype(np.int64)[:, None, None] + off[None, None, :]
    iy = np.rint((pts[:, 1] - gy[0]) / step).astype(np.int64)[:, None, None] + off[None, :, None]
    ix, iy = np.broadcast_arrays(ix, iy)                                   # [G, 2w+1, 2w+1]
    ok = (ix >= 0) & (ix < len(gx)) & (iy >= 0) & (iy < len(gy))
    d = np.stack([gx[ix.clip(0, len(gx) - 1)], gy[iy.clip(0, len(gy) - 1)]], -1) - pts[:, None, None, :]
    val = np.exp(-0.5 * np.einsum("gija,gab,gijb->gij", d, inv, d)) * ok
    flat = (iy.clip(0, len(gy) - 1) * len(gx) + ix.clip(0, len(gx) - 1)).ravel()
    return np.bincount(flat, weights=val.ravel(), minlength=len(gx) * len(gy)).reshape(len(gy), len(gx))


@dataclass
class PatchCoverage:
    """A planar patch's coverage C(x) in its plane (the sum of its members' Gaussians, `_coverage_2d`): the
    basis [3, 2] at point [3] m, the members' in-plane means pts [G, 2] m and covariances cov2 [G, 2, 2] m^2,
    the window reach m, C on the grid gx x gy (grid [len(gy), len(gx)]) and the level at half its interior
    value, whose level line is the patch's boundary (on a tiling's border, surfels.py)."""

    basis: np.ndarray
    point: np.ndarray
    pts: np.ndarray
    cov2: np.ndarray
    reach: float
    gx: np.ndarray
    gy: np.ndarray
    grid: np.ndarray
    level: float

    def inside(self, c: np.ndarray) -> np.ndarray:
        """[N] bool: points c [N, 3] m on the patch's plane lie within its boundary (C >= level)."""
        if len(c) == 0:
            return np.zeros(0, bool)
        return _coverage_2d(self.pts, self.cov2, (c - self.point) @ self.basis, self.reach) >= self.level


def patch_coverage(x: np.ndarray, cov: np.ndarray, normal: np.ndarray, point: np.ndarray, half: float) -> PatchCoverage:
    """The coverage of one patch (members' means x [G, 3] m, covariances cov [G, 3, 3] m^2; normal [3], point [3] m
    its plane; half m the members' median half-side), sampled every 0.4 half-sides."""
    ref = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(normal, ref)
    e1 /= np.linalg.norm(e1)
    basis = np.stack([e1, np.cross(normal, e1)], 1)                        # [3, 2]
    pts = (x - point) @ basis
    cov2 = np.einsum("ia,gij,jb->gab", basis, cov, basis) + np.eye(2) * (1e-3 * half) ** 2
    reach = 3.0 * float(np.sqrt(np.linalg.eigvalsh(cov2)[:, -1].max()))
    step = 0.4 * half
    lo, hi = pts.min(0) - 2 * reach, pts.max(0) + 2 * reach
    gx = np.arange(lo[0], hi[0] + step, step)
    gy = np.arange(lo[1], hi[1] + step, step)
    c = _coverage_grid(pts, cov2, gx, gy, reach)
    return PatchCoverage(basis, np.asarray(point, np.float64), pts, cov2, reach, gx, gy, c,
                         0.5 * float(c[c > 0.5 * c.max()].mean()))


def _straight_runs(simple: np.ndarray) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """The pieces (a, b) of polyline `simple` [P, 2] with the ends (run_a, run_b) of the straight run each
    belongs to: consecutive pieces within WEDGE_T_COS of the run's first direction (a closed line starts at a
    corner, so that no run is cut by where the contour began)."""
    pts = simple
    d = np.diff(pts, axis=0)
    ok = np.hypot(d[:, 0], d[:, 1]) > 1e-9
    if not ok.any():
        return []
    closed = len(pts) > 3 and np.allclose(pts[0], pts[-1])
    pieces = [(pts[i], pts[i + 1]) for i in np.nonzero(ok)[0]]
    unit = lambda a, b: (b - a) / np.hypot(*(b - a))  # noqa: E731
    if closed:
        turn = [i for i in range(len(pieces)) if unit(*pieces[i]) @ unit(*pieces[i - 1]) < WEDGE_T_COS]
        if turn:
            pieces = pieces[turn[0]:] + pieces[:turn[0]]
    out, start = [], 0
    for i in range(1, len(pieces) + 1):
        if i == len(pieces) or unit(*pieces[i]) @ unit(*pieces[start]) < WEDGE_T_COS:
            out += [(a, b, pieces[start][0], pieces[i - 1][1]) for a, b in pieces[start:i]]
            start = i
    return out


def patch_coverage_of(patches, p: int, x: np.ndarray, cov: np.ndarray, cells: np.ndarray) -> tuple[PatchCoverage, float]:
    """(patch_coverage of patch p of patches (second_order.Patches), its members' median half-side m), from the
    Gaussians' means x [G, 3] m, covariances cov [G, 3, 3] m^2 and cells [G, 2, 3] m (surfels.footprint_cells);
    computed once per set of patches: the edge waves' boundary and the double bounce's aperture share it."""
    if p not in patches.coverage:
        members = patches.members[p]
        half = float(np.median(np.linalg.norm(cells[members], axis=2)))
        patches.coverage[p] = (patch_coverage(x[members], cov[members], patches.normal[p], patches.point[p], half),
                               half)
    return patches.coverage[p]


def _patch_boundary(cover: PatchCoverage, half: float) -> list[tuple[np.ndarray, np.ndarray, np.ndarray, float]]:
    """Straight boundary pieces of one patch: (mid [3] m, tangent [3], inward [3], length m, (lo, hi) m: the
    straight line's extent along the tangent from the segment's midpoint), from the level line of its
    coverage (patch_coverage: half the interior coverage of the members); half: the members' median
    half-side (m)."""
    import contourpy

    basis, point, pts, cov2, reach = cover.basis, cover.point, cover.pts, cover.cov2, cover.reach
    lines = contourpy.contour_generator(cover.gx, cover.gy, cover.grid).lines(cover.level)
    mids, tans, lens, spans = [], [], [], []
    for line in lines:
        line = np.asarray(line)
        if len(line) < 3:
            continue
        simple = _simplify(line, 0.25 * half)
        for a, b, run_a, run_b in _straight_runs(simple):
            seg = b - a
            length = float(np.hypot(*seg))
            pieces = max(1, int(math.ceil(length / (2.0 * half))))
            for i in range(pieces):
                m = a + seg * (i + 0.5) / pieces
                mids.append(m)
                tans.append(seg / length)
                lens.append(length / pieces)
                spans.append(tuple(sorted(((run_a - m) @ (seg / length), (run_b - m) @ (seg / length)))))
    if not mids:
        return []
    m2, t2 = np.array(mids), np.array(tans)
    n2 = np.stack([-t2[:, 1], t2[:, 0]], 1)
    probe = _coverage_2d(pts, cov2, np.concatenate([m2 + 0.5 * half * n2, m2 - 0.5 * half * n2]), reach)
    inward = np.where((probe[:len(m2)] >= probe[len(m2):])[:, None], n2, -n2)    # toward the covered side
    return [(point + basis @ m, basis @ t, basis @ i, ln, sp) for m, t, i, ln, sp in zip(m2, t2, inward, lens, spans)]


def patch_edges(geom: FrozenGeometry, cov: torch.Tensor, cells: torch.Tensor, patches) -> Edges:
    """The outer edges of the planar patches (module docstring). cov [G, 3, 3] m^2: the Gaussians'
    covariances; cells [G, 2, 3] m: surfels.footprint_cells; patches: second_order.Patches."""
    from scipy.spatial import cKDTree

    x = geom.means.numpy()
    cv = cov.numpy()
    c = cells.numpy()
    pieces, patch, near = [], [], []
    for p, members in enumerate(patches.members):
        cover, half = patch_coverage_of(patches, p, x, cv, c)
        tree = cKDTree(x[members])
        for mid, t, inward, length, span in _patch_boundary(cover, half):
            pieces.append((mid, t, inward, length, half, span))
            patch.append(p)
            near.append(members[tree.query(mid + 0.5 * half * inward)[1]])
    if not pieces:
        return _empty_edges()
    mid = np.array([q[0] for q in pieces])
    tangent = np.array([q[1] for q in pieces])
    face = np.array([q[2] for q in pieces])
    length = np.array([q[3] for q in pieces])
    half = np.array([q[4] for q in pieces])
    span = np.array([q[5] for q in pieces])
    patch, s_id = np.asarray(patch), np.asarray(near)
    # wedges: an outer edge lying on another patch's outer edge (a fold, a box's edge, a sheet's two faces)
    face_b, gauss_b = face.copy(), s_id.copy()
    _, cand = cKDTree(mid).query(mid, k=min(8, len(mid)), distance_upper_bound=float(length.max() + half.max()))
    cand = cand.reshape(len(mid), -1)
    valid = cand < len(mid)
    j = np.where(valid, cand, 0)
    off = mid[j] - mid[:, None]                                            # [E, C, 3]
    along = np.einsum("ecj,ej->ec", off, tangent)
    across = np.linalg.norm(off - along[..., None] * tangent[:, None], axis=-1)
    ok = valid & (patch[j] != patch[:, None]) & (np.abs(np.einsum("ej,ecj->ec", tangent, tangent[j])) >= WEDGE_T_COS)
    # each level line is uncertain by a fraction of a surfel, most on a patch one or two surfels wide (a
    # facet of a curved surface): there two facets' lines miss each other by up to a half-side, and an
    # unpaired pair of lines would count as two half-plane edges where the surface has none
    ok &= across <= WEDGE_ACROSS_HALF * np.maximum(half[:, None], half[j])
    ok &= np.abs(along) <= 0.5 * (length[:, None] + length[j])
    dist = np.where(ok, np.linalg.norm(off, axis=-1), np.inf)
    has = ok.any(1)
    best = j[np.arange(len(mid)), dist.argmin(1)]
    keep = ~(has & (patch > patch[best]))          # a wedge is kept on the lower-numbered patch's edge
    pair = has & (patch < patch[best])
    face_b[pair], gauss_b[pair] = face[best[pair]], s_id[best[pair]]
    t = lambda a: torch.as_tensor(np.ascontiguousarray(a[keep]))  # noqa: E731
    opposite, width = _opposite_edges(mid[keep], tangent[keep], face[keep], face_b[keep], length[keep], half[keep],
                                      patch[keep])
    fold, fold_width = _fold_edges(mid[keep], tangent[keep], face[keep], face_b[keep], length[keep], half[keep])
    return Edges(t(mid), t(tangent), t(length), t(face), t(face_b), t(s_id).long(), t(gauss_b).long(),
                 torch.as_tensor(opposite), torch.as_tensor(width), t(span), torch.as_tensor(fold),
                 torch.as_tensor(fold_width))


def _opposite_edges(mid: np.ndarray, tangent: np.ndarray, face: np.ndarray, face_b: np.ndarray, length: np.ndarray,
                    half: np.ndarray, patch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each half-plane edge segment (a sheet's edge: both faces' directions equal), the segment of the same
    patch straight across it on a parallel half-plane edge facing it (inward directions opposite), the nearest
    such: (opposite [E] int64, -1 for none; width [E] m, the distance across along the inward direction)."""
    num = len(mid)
    opposite, width = np.full(num, -1, dtype=np.int64), np.zeros(num)
    sheet = np.einsum("ej,ej->e", face, face_b) >= WEDGE_T_COS
    for p in np.unique(patch):
        idx = np.nonzero((patch == p) & sheet)[0]
        if len(idx) < 2:
            continue
        off = mid[idx][None] - mid[idx][:, None]                               # [A, B, 3]: from A to B
        across = np.einsum("abj,aj->ab", off, face[idx])
        along = np.abs(np.einsum("abj,aj->ab", off, tangent[idx]))
        ok = (np.abs(tangent[idx] @ tangent[idx].T) >= WEDGE_T_COS) & (face[idx] @ face[idx].T <= -WEDGE_T_COS)
        ok &= (across > 2.0 * half[idx][:, None]) & (along <= 0.5 * (length[idx][:, None] + length[idx][None]))
        _keep_nearest(ok, across, idx, idx, opposite, width)
    return opposite, width


def _keep_nearest(ok: np.ndarray, across: np.ndarray, rows: np.ndarray, cols: np.ndarray, index_out: np.ndarray,
                  width_out: np.ndarray) -> None:
    """For each row r with an acceptable column (ok [R, C] bool), the nearest one (smallest across [R, C] m):
    index_out[rows[r]] = cols[c], width_out[rows[r]] = across[r, c] (rows [R], cols [C] edge indices)."""
    has = ok.any(1)
    best = np.where(ok, across, np.inf).argmin(1)
    index_out[rows[has]] = cols[best[has]]
    width_out[rows[has]] = across[has, best[has]]


def _fold_edges(mid: np.ndarray, tangent: np.ndarray, face: np.ndarray, face_b: np.ndarray, length: np.ndarray,
                half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each half-plane edge segment O (both faces' directions equal; mid, tangent, face, face_b [E, 3],
    length, half [E] m as in `patch_edges`), the nearest segment of a fold (a wedge of two faces, neither a
    half-plane nor a flat continuation) straight across O in O's plane, parallel, one of whose faces points back
    to O (the wave along that face joins the two): (fold [E] int64, -1 for none; fold_width [E] m, the distance
    across along O's inward direction)."""
    num = len(mid)
    fold, width = np.full(num, -1, dtype=np.int64), np.zeros(num)
    cos_ab = np.einsum("ej,ej->e", face, face_b)
    si = np.nonzero(cos_ab >= WEDGE_T_COS)[0]                                 # half-planes
    wi = np.nonzero((cos_ab < WEDGE_T_COS) & (cos_ab > -WEDGE_T_COS))[0]       # folds
    if not len(si) or not len(wi):
        return fold, width
    chunk = max(1, 1_000_000 // len(wi))                # half-plane rows per pass: [S, W, 3] arrays stay small
    for a in range(0, len(si), chunk):
        sc = si[a:a + chunk]
        off = mid[wi][None] - mid[sc][:, None]                             # [S, W, 3]: from the edge to the fold
        across = np.einsum("swj,sj->sw", off, face[sc])
        along = np.einsum("swj,sj->sw", off, tangent[sc])
        aside = np.linalg.norm(off - across[..., None] * face[sc][:, None] - along[..., None] * tangent[sc][:, None],
                               axis=-1)                                   # off the half-plane's plane
        back = np.minimum(face[sc] @ face[wi].T, face[sc] @ face_b[wi].T)
        ok = (np.abs(tangent[sc] @ tangent[wi].T) >= WEDGE_T_COS) & (back <= -WEDGE_T_COS)
        ok &= (across > 2.0 * half[sc][:, None]) & (np.abs(along) <= 0.5 * (length[sc][:, None] + length[wi][None]))
        ok &= aside <= 0.5 * np.maximum(half[sc][:, None], half[wi][None])
        _keep_nearest(ok, across, sc, wi, fold, width)
    return fold, width


def _gtd_minus_po(phi: torch.Tensor, n: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(f_s, f_h) of wedge_fringe without its treatment of the singular angles."""
    s = torch.sin(math.pi / n)
    cn = torch.cos(math.pi / n)
    t1 = 1.0 / (cn - 1.0)
    t2 = 1.0 / (cn - torch.cos(2.0 * phi / n))
    a_s = (2.0 * s / n) * (t1 - t2)
    a_h = -(2.0 * s / n) * (t1 + t2)
    po = torch.where(phi < math.pi, torch.tan(phi), torch.zeros_like(phi)) \
        + torch.where(n * math.pi - phi < math.pi, torch.tan(n * math.pi - phi), torch.zeros_like(phi))
    return a_s - po, a_h - po


def wedge_fringe(phi: torch.Tensor, n: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(f_s, f_h) [...]: the monostatic fringe coefficients of a perfectly conducting wedge of exterior
    angle n pi (1 < n <= 2) at angle phi from face 0 (0 <= phi <= n pi), in the units of the module
    docstring (GTD backscatter minus the PO edge terms of the lit faces; finite everywhere).
    Near a face's normal (phi = pi / 2 or n pi - pi / 2) both are singular: averaged at +-SINGULAR_RAD."""
    phi, n = torch.broadcast_tensors(phi.double(), torch.as_tensor(n, dtype=torch.float64))
    near = ((phi - math.pi / 2).abs() < SINGULAR_RAD) | ((n * math.pi - math.pi / 2 - phi).abs() < SINGULAR_RAD)
    lo_s, lo_h = _gtd_minus_po(torch.where(near, phi - SINGULAR_RAD, phi), n)
    hi_s, hi_h = _gtd_minus_po(torch.where(near, phi + SINGULAR_RAD, phi), n)
    f_s = torch.where(near, 0.5 * (lo_s + hi_s), lo_s)
    f_h = torch.where(near, 0.5 * (lo_h + hi_h), lo_h)
    flat = n < 1.0 + 1e-9                       # no edge (a plane continues)
    return torch.where(flat, 0.0, f_s), torch.where(flat, 0.0, f_h)


@dataclass
class EdgeTerms:
    """Edge items (link, edge segment): link [I]; gauss_a, gauss_b [I] (the materials of the two faces);
    coef [I, K] complex: the edge's field without rho_e (module docstring); freq_hz [K]."""

    num_links: int
    link: torch.Tensor
    gauss_a: torch.Tensor
    gauss_b: torch.Tensor
    coef: torch.Tensor
    freq_hz: torch.Tensor

    @property
    def num(self) -> int:
        return int(self.link.numel())

    def select_links(self, rows) -> "EdgeTerms":
        rows, keep, new_link = renumber_links(self.link, self.num_links, rows)
        return EdgeTerms(int(rows.numel()), new_link, self.gauss_a[keep], self.gauss_b[keep],
                         self.coef[keep], self.freq_hz)

    def at_columns(self, a: int, b: int) -> "EdgeTerms":
        """The same items at frequencies a..b-1."""
        return EdgeTerms(self.num_links, self.link, self.gauss_a, self.gauss_b, self.coef[:, a:b], self.freq_hz[a:b])


def edge_terms(edges: Edges, links: LinkSet, tx_ant: AntennaPattern, rx_ant: AntennaPattern, lit,
               polarisation: str = "V", colocated_tol_m: float = 0.01, link_chunk: int = 64) -> EdgeTerms:
    """Edge items of every co-located link (module docstring). lit(link [Q], gauss [Q]) -> V [Q]: whether
    a surfel is lit from the link's radar (1 or 0; traced whatever the surfel's orientation, so that an
    edge seen edge-on keeps its echo)."""
    freq = links.freq_hz.double()
    k0 = 2 * math.pi * freq / C0                                          # [K]
    parts = []
    colocated = (links.tx_m - links.rx_m).norm(dim=-1) < colocated_tol_m
    if edges.num and bool(colocated.any()):
        e1 = edges.face_a
        e2 = torch.linalg.cross(edges.tangent, e1, dim=-1)
        psi_b = torch.remainder(torch.atan2((edges.face_b * e2).sum(-1), (edges.face_b * e1).sum(-1)), 2 * math.pi)
        psi_b = torch.where(psi_b > 2 * math.pi - 1e-9, torch.zeros_like(psi_b), psi_b)
        from_b = psi_b <= math.pi                      # face 0 is B, the exterior runs from B to A the long way
        n_ext = torch.where(from_b, 2.0 - psi_b / math.pi, psi_b / math.pi)
        n_ext = torch.where(n_ext < 1e-9, torch.full_like(n_ext, 2.0), n_ext)   # psi_b = 2 pi: a half-plane
        idx = torch.nonzero(colocated).flatten()
        for a in range(0, idx.numel(), link_chunk):
            lk = idx[a:a + link_chunk]
            radar = 0.5 * (links.tx_m[lk] + links.rx_m[lk])
            vec = radar[:, None] - edges.mid[None]                        # [m, E, 3]
            d = vec.norm(dim=-1)
            s = vec / d[..., None]
            st = (s * edges.tangent[None]).sum(-1)
            sp = s - st[..., None] * edges.tangent[None]
            sin_b = sp.norm(dim=-1)
            psi = torch.remainder(torch.atan2((sp * e2[None]).sum(-1), (sp * e1[None]).sum(-1)), 2 * math.pi)
            phi = torch.where(from_b[None], torch.remainder(psi - psi_b[None], 2 * math.pi), psi)
            m_i, e_i = ((phi <= n_ext[None] * math.pi) & (sin_b > 1e-6)).nonzero(as_tuple=True)   # outside the wedge
            vis = _edge_lit(lit, edges, lk[m_i], e_i)
            if bool((edges.opposite >= 0).any()):
                parts.append(_double_terms(edges, lk, radar, m_i[vis > 0], e_i[vis > 0], phi, s, d, st, sin_b, k0,
                                           lambda q, e: _edge_lit(lit, edges, q, e), tx_ant, rx_ant, links,
                                           polarisation))
            if bool((edges.fold >= 0).any()):
                parts.append(_fold_terms(edges, lk, radar, m_i[vis > 0], e_i[vis > 0], phi, n_ext, from_b, s, d, st,
                                         sin_b, k0, lambda q, e: _edge_lit(lit, edges, q, e), tx_ant, rx_ant, links,
                                         polarisation))
            m_i, e_i, vis = m_i[vis > 0], e_i[vis > 0], vis[vis > 0]
            if m_i.numel() == 0:
                continue
            f_s, f_h = wedge_fringe(phi[m_i, e_i].clamp(max=2 * math.pi), n_ext[e_i])
            sv = s[m_i, e_i]
            p = antenna_polarisation(sv, polarisation)
            t_perp = (edges.tangent[e_i] - st[m_i, e_i][:, None] * sv) / sin_b[m_i, e_i].clamp(min=1e-12)[:, None]
            w_s = ((p * t_perp).sum(-1) ** 2).clamp(0.0, 1.0)
            amp = w_s * f_s + (1.0 - w_s) * f_h                                # [I]
            g_t = tx_ant.gain(-sv, links.tx_axis[lk][m_i])
            g_r = rx_ant.gain(-sv, links.rx_axis[lk][m_i])
            dd, ln = d[m_i, e_i], edges.length[e_i]
            base = torch.sqrt(g_t * g_r) * vis * amp * ln / (8 * math.pi * dd**2)   # [I]
            along = torch.sinc(ln[:, None] * st[m_i, e_i][:, None] * k0[None] / math.pi)          # [I, K]
            coef = (base[:, None] / k0[None]) * along * torch.exp(-2j * dd[:, None] * k0[None])
            parts.append((lk[m_i], edges.gauss_a[e_i], edges.gauss_b[e_i], coef))
    if not parts:
        z = torch.zeros(0, dtype=torch.int64)
        return EdgeTerms(links.num, z, z, z, torch.zeros((0, int(freq.numel())), dtype=torch.complex128), freq)
    return EdgeTerms(links.num, torch.cat([q[0] for q in parts]), torch.cat([q[1] for q in parts]),
                     torch.cat([q[2] for q in parts]), torch.cat([q[3] for q in parts]), freq)


def _edge_lit(lit, edges: Edges, link: torch.Tensor, e: torch.Tensor) -> torch.Tensor:
    """V [Q] of edge segments e [Q] from links [Q]: lit when a surfel of either face next to it is."""
    ga, gb = edges.gauss_a[e], edges.gauss_b[e]
    vis = lit(link, ga)
    other = (gb != ga) & (vis <= 0)
    if bool(other.any()):
        vis[other] = lit(link[other], gb[other])
    return vis


def utd_transition(x: np.ndarray) -> np.ndarray:
    """The Kouyoumjian-Pathak transition function F(X) = 2 j sqrt(X) exp(j X) int_sqrt(X)^inf exp(-j t^2) dt
    [...] complex (X >= 0; F -> 1 for X >> 1, F ~ sqrt(pi X) exp(j pi / 4) for X -> 0; exp(+j omega t))."""
    from scipy.special import fresnel

    x = np.asarray(x, dtype=np.float64)
    s_f, c_f = fresnel(np.sqrt(2.0 * x / math.pi))
    tail = math.sqrt(math.pi / 2) * ((0.5 - c_f) - 1j * (0.5 - s_f))
    return 2j * np.sqrt(x) * np.exp(1j * x) * tail


def _crossing(kw: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K, 1 / (1 - K^2 / 4)) [...] complex of a sheet of width w crossed in the hard case (kw = k w):
    K = -2 exp(-j (kw + pi / 4)) / sqrt(2 pi kw), one crossing from edge to edge between Keller's coefficients
    (the factor 2: the wave on a zero-thickness sheet is odd across it, both faces' grazing waves diffract), and
    the sum of the further round trips, each an edge's backscatter along its face (grazing in and out:
    coefficient 2 g(0) = 2) and two crossings, the geometric series 1 + K^2 / 4 + (K^2 / 4)^2 + ..."""
    kw = np.asarray(kw, dtype=np.float64)
    k_cross = -2.0 * np.exp(-1j * (kw + math.pi / 4)) / np.sqrt(2 * math.pi * kw)
    return k_cross, 1.0 / (1.0 - 0.25 * k_cross**2)


def strip_double_diffraction(phi_a: np.ndarray, phi_b: np.ndarray, kw: np.ndarray) -> np.ndarray:
    """Backscatter coefficient [...] complex of the wave diffracted at edge B of a perfectly conducting strip
    (E across the edges: hard), carried across its face to edge A (width w, kw = k w) and diffracted there
    back to the radar, in the units of `wedge_fringe` and relative to the phase of the path radar-B-A-radar
    without the crossing: K g(phi_a) g(phi_b) / (1 - K^2 / 4) (`_crossing`: Keller's coefficient twice, the
    wave on the face odd across the sheet, and the further round trips between the edges; g(phi) =
    `wedge_grazing_vertex`(phi, 2, kw): sec(phi / 2), with the UTD transition function at the edge beyond which
    the radar lies). phi_a, phi_b:
    the radar's angle from each edge's face, 0..pi (the side of the sheet the radar is on). A soft (E along the
    edges) field vanishes on the face: no such term."""
    kw = np.asarray(kw, dtype=np.float64)
    k_cross, series = _crossing(kw)
    return k_cross * wedge_grazing_vertex(phi_a, 2.0, kw) * wedge_grazing_vertex(phi_b, 2.0, kw) * series


def strip_return_diffraction(phi_a: np.ndarray, kw: np.ndarray) -> np.ndarray:
    """Backscatter coefficient [...] complex of the wave diffracted at edge A of the strip, carried across to
    the facing edge B, diffracted back along the face (grazing in and out: coefficient 2) and diffracted at A
    to the radar, with the further round trips (units and phase reference as `strip_double_diffraction`, the
    path radar-A-B-A-radar without its two crossings): (K^2 / 2) g(phi_a)^2 / (1 - K^2 / 4). Near grazing
    beyond A (phi_a -> pi) it is as large as the first-order and doubly diffracted waves: with them, B's
    diffraction of the total field at B (the plane wave and A's diffracted wave, which cancel there as
    the radar reaches the sheet's plane) radiated both directly and by way of A, so that the hard sheet's echo
    vanishes at grazing as (cos theta)^4 (theta from the normal), as the exact one does."""
    kw = np.asarray(kw, dtype=np.float64)
    k_cross, series = _crossing(kw)
    return 0.5 * k_cross**2 * wedge_grazing_vertex(phi_a, 2.0, kw) ** 2 * series


def _double_terms(edges: Edges, lk, radar, m_i, e_i, phi, s, d, st, sin_b, k0, vis_of, tx_ant, rx_ant, links,
                  polarisation):
    """Items (link, segment A) of the doubly diffracted wave B -> A (strip_double_diffraction) for the lit items
    (m_i, e_i) of one link chunk whose segment has an opposite B: the radar's field diffracted at B, carried
    across the patch (width w) and diffracted at A back to the radar, radiated along A as its first-order
    current (the sinc) with the hard share w_h of the polarisation, phase exp(-j k (d_A + d_B' + w sin beta)),
    B' the point across from A's midpoint. In the plane across the edges (sin beta = |s x t|) the wavenumber
    is k sin beta (Keller's cone); the ray that reaches A left B's line w (s.t) / sin(beta) along the edge
    from B', and an item exists only where that point lies on B's straight run (`Edges.span`): an oblique
    wave leaves a finite plate before it reaches the other edge. The item also carries the return path
    radar-A-B-A-radar (`strip_return_diffraction`, phase exp(-j k (2 d_A + 2 w sin beta))) when the point where
    that ray left A, 2 w (s.t) / sin(beta) along A's line from its midpoint, lies on A's straight run.
    Returns (link [I], gauss_a [I], gauss_b [I], coef [I, K])."""
    opp = edges.opposite[e_i]
    sel = opp >= 0
    m_i, e_i, opp = m_i[sel], e_i[sel], opp[sel]
    if m_i.numel():
        vis = vis_of(lk[m_i], opp)
        m_i, e_i, opp = m_i[vis > 0], e_i[vis > 0], opp[vis > 0]
    if m_i.numel() == 0:
        z = torch.zeros(0, dtype=torch.int64)
        return z, z, z, torch.zeros((0, int(k0.numel())), dtype=torch.complex128)
    # Keller's cone: the ray reaching A's midpoint left B's line w (s.t) / sin(beta) along the edge from the point
    # across; it exists only if that point lies on B's straight line (an oblique wave leaves a finite plate)
    w = edges.width[e_i]
    sb = sin_b[m_i, e_i]
    origin = edges.mid[e_i] + w[:, None] * edges.face_a[e_i] \
        + (w * st[m_i, e_i] / sb.clamp(min=1e-12))[:, None] * edges.tangent[e_i]
    u = ((origin - edges.mid[opp]) * edges.tangent[opp]).sum(-1)
    on = (u >= edges.span[opp, 0]) & (u <= edges.span[opp, 1])
    m_i, e_i, opp, w, sb = m_i[on], e_i[on], opp[on], w[on], sb[on]
    if m_i.numel() == 0:
        z = torch.zeros(0, dtype=torch.int64)
        return z, z, z, torch.zeros((0, int(k0.numel())), dtype=torch.complex128)
    # the return path A -> B -> A: its ray leaves A's line 2 w (s.t) / sin(beta) from A's midpoint, on A's run
    back = 2.0 * w * st[m_i, e_i] / sb.clamp(min=1e-12)
    ret = ((back >= edges.span[e_i, 0]) & (back <= edges.span[e_i, 1])).numpy()
    fold = lambda x: torch.where(x > math.pi, 2 * math.pi - x, x)  # noqa: E731  the radar's side of the sheet
    kw = (k0[None] * (w * sb)[:, None]).numpy()                                  # [I, K]
    pa = fold(phi[m_i, e_i]).numpy()[:, None]
    pb = fold(phi[m_i, opp]).numpy()[:, None]
    amp = torch.as_tensor(strip_double_diffraction(pa, pb, kw))               # [I, K]
    amp_ret = torch.as_tensor(strip_return_diffraction(pa, kw) * ret[:, None])  # [I, K]
    scale, dd, d_b = _hard_item_radiation(edges, lk, radar, m_i, e_i, w, s, d, st, sb, k0, tx_ant, rx_ant, links,
                                          polarisation)
    # radar-B-A-radar and radar-A-B-A-radar (its crossings' phase is in amp_ret): one item of A
    coef = scale * (amp * torch.exp(-1j * (dd + d_b)[:, None] * k0[None])
                    + amp_ret * torch.exp(-2j * dd[:, None] * k0[None]))
    return lk[m_i], edges.gauss_a[e_i], edges.gauss_a[opp], coef


def _hard_item_radiation(edges: Edges, lk, radar, m_i, e_i, w, s, d, st, sb, k0, tx_ant, rx_ant, links, polarisation):
    """(scale [I, K], d_a [I] m, d_b [I] m) of items (link lk[m_i], edge e_i) whose wave crosses a width w [I] m from
    edge A (e_i) along its face: scale radiates the item along A as A's first-order current (the sinc along its
    length, the antennas' gains in the radar direction s, the hard share w_h of the polarisation, in the units of
    `wedge_fringe`, divided by k); d_a is the radar's distance to A's midpoint and d_b to the point across from it
    (their sum is the phase path of a wave that leaves or ends at the far side)."""
    sv = s[m_i, e_i]
    p = antenna_polarisation(sv, polarisation)
    t_perp = (edges.tangent[e_i] - st[m_i, e_i][:, None] * sv) / sb.clamp(min=1e-12)[:, None]
    w_h = 1.0 - ((p * t_perp).sum(-1) ** 2).clamp(0.0, 1.0)
    g_t = tx_ant.gain(-sv, links.tx_axis[lk][m_i])
    g_r = rx_ant.gain(-sv, links.rx_axis[lk][m_i])
    d_a, ln = d[m_i, e_i], edges.length[e_i]
    d_b = (radar[m_i] - (edges.mid[e_i] + w[:, None] * edges.face_a[e_i])).norm(dim=-1)
    base = torch.sqrt(g_t * g_r) * w_h * ln / (8 * math.pi * d_a**2)
    along = torch.sinc(ln[:, None] * st[m_i, e_i][:, None] * k0[None] / math.pi)
    return (base[:, None] / k0[None]) * along, d_a, d_b


def wedge_grazing_vertex(phi: np.ndarray, n: np.ndarray, kw: np.ndarray) -> np.ndarray:
    """h(phi, n) [...] complex: Keller's hard coefficient of a perfectly conducting wedge (exterior angle n pi)
    between the radar at angle phi from face 0 (0..n pi) and a wave grazing along face 0 (arriving or leaving),
    with the factor 1/2 of grazing incidence, relative to its value at phi = 0 for a half-plane (n = 2, F = 1:
    sec(phi / 2)):
        h = (1 / n) [cot((pi + phi) / (2 n)) + cot((pi - phi) / (2 n)) F(2 kw cos^2(phi / 2))]
          = -(2 sin(pi / n) / n) / (cos(pi / n) - cos(phi / n))   (F = 1);
    the UTD transition function F (`utd_transition`; kw = k w, w the distance to the other end of the grazing
    path) multiplies the one term that is singular at the shadow boundary of the grazing wave (phi = pi: the
    radar in face 0's plane beyond the edge), where the radar is beyond the face's normal (phi > pi / 2); Keller's
    F = 1 elsewhere. There the term tends to +-sqrt(2 pi kw) (sign of pi - phi, the diffracted wave's jump that
    makes the total field continuous). Why F = 1 on the near side (phi <= pi / 2): the wave arriving along the
    face is there, near grazing, minus the part of the radar's own plane wave that the near edge's shadow
    removes, and must be diffracted with the same plane-wave coefficient as that plane wave for the two to
    cancel as the exact sheet's do (the transition function's 1 / kw remainder, F(X) ~ 1 + j / (2 X), is below
    the theory's accuracy but would leave a hard sheet an echo at grazing). n = 1.5 (a 90-degree fold seen from outside):
    h(0) = 4 / (3 sqrt(3)) = 0.770."""
    phi, n, kw = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64) for x in (phi, n, kw)))
    x = (math.pi - phi) / (2.0 * n)
    x = np.where(np.abs(x) < 1e-9, 1e-9, x)          # F -> 0 there: the product stays finite
    near = phi > 0.5 * math.pi
    f = np.where(near, utd_transition(np.where(near, 2.0 * kw * np.cos(0.5 * phi) ** 2, 1.0)), 1.0)
    return (1.0 / np.tan((math.pi + phi) / (2.0 * n)) + f / np.tan(x)) / n


def _fold_terms(edges: Edges, lk, radar, m_i, e_i, phi, n_ext, from_b, s, d, st, sin_b, k0, vis_of, tx_ant, rx_ant,
                links, polarisation):
    """Items (link, outer edge O) of the waves between a half-plane edge O and the fold F across its face (width
    w, `Edges.fold`) along the fold's outer face, for the lit items (m_i, e_i) of one link chunk, in the hard case
    (E across the edges), in the units of `wedge_fringe`: the radar's field diffracted at O, carried along the
    face's outer side, grazing, and diffracted at F back to the radar, and the reverse (F -> O; in backscatter the
    same phase):
        K(w) h(phi_O, 2) h(phi_F, n_F),
    relative to the phase exp(-j k (d_O + d_F')) of the path without the crossing (F' the fold's point across
    from O's midpoint); K = `_crossing` (a crossing of w sin beta at wavenumber k between Keller's coefficients;
    its factor 2 is here the two directions, the wave running along one face only), h = `wedge_grazing_vertex`;
    phi_O from O's face through its outer side (away from the fold's other face; 0..2 pi: the wave leaves O along
    that side whichever side the radar is on), phi_F from the fold's face toward O through the exterior (0..n_F pi;
    outside that, in the concave corner, the fold's exterior does not see the radar; F must be lit). A soft field
    vanishes on the face: no such term. The wave along the face's inner side into a concave fold is not here
    (docs/physics.md section 8.13: its return near the plate's plane is PO's specular flash of the other plate).
    Radiated along O as its first-order current (the sinc) with the hard share w_h; an item exists where the ray
    reaching O's midpoint left the fold on its straight run (Keller's cone, as `_double_terms`). Returns
    (link [I], gauss_a [I], gauss_b [I], coef [I, K])."""
    fold = edges.fold[e_i]
    sel = fold >= 0
    m_i, e_i, fold = m_i[sel], e_i[sel], fold[sel]
    none = (torch.zeros(0, dtype=torch.int64),) * 3 + (torch.zeros((0, int(k0.numel())), dtype=torch.complex128),)
    if m_i.numel() == 0:
        return none
    w = edges.fold_width[e_i]
    sb = sin_b[m_i, e_i].clamp(min=1e-12)
    cone = w * st[m_i, e_i] / sb                       # along O's tangent, where the ray meets the fold's line
    origin = edges.mid[e_i] + w[:, None] * edges.face_a[e_i] + cone[:, None] * edges.tangent[e_i]
    u = ((origin - edges.mid[fold]) * edges.tangent[fold]).sum(-1)
    on = (u >= edges.span[fold, 0]) & (u <= edges.span[fold, 1])
    m_i, e_i, fold, w, sb = (x[on] for x in (m_i, e_i, fold, w, sb))
    if m_i.numel() == 0:
        return none
    # which of the fold's faces runs back to O; phi_F from it; the radar outside the wedge and the fold lit
    path = -edges.face_a[e_i]
    path_is_a = (edges.face_a[fold] * path).sum(-1) >= (edges.face_b[fold] * path).sum(-1)
    n_f = n_ext[fold]
    phi_f = torch.where(path_is_a ^ from_b[fold], phi[m_i, fold], n_f * math.pi - phi[m_i, fold])
    outside = (phi[m_i, fold] <= n_f * math.pi) & (sin_b[m_i, fold] > 1e-6)
    if bool(outside.any()):
        outside[outside.clone()] = vis_of(lk[m_i[outside]], fold[outside]) > 0
    m_i, e_i, fold, w, sb, phi_f, n_f, path_is_a = (
        x[outside] for x in (m_i, e_i, fold, w, sb, phi_f, n_f, path_is_a))
    if m_i.numel() == 0:
        return none
    # phi_O through the outer side of O's face: the side away from the fold's other face
    other = torch.where(path_is_a[:, None], edges.face_b[fold], edges.face_a[fold])
    e2 = torch.linalg.cross(edges.tangent[e_i], edges.face_a[e_i], dim=-1)
    phi_o = torch.where((other * e2).sum(-1) < 0, phi[m_i, e_i], 2 * math.pi - phi[m_i, e_i]).numpy()[:, None]
    kw = (k0[None] * (w * sb)[:, None]).numpy()                                  # [I, K]
    k_cross, _ = _crossing(kw)
    amp = torch.as_tensor(k_cross * wedge_grazing_vertex(phi_o, 2.0, kw)
                          * wedge_grazing_vertex(phi_f.numpy()[:, None], n_f.numpy()[:, None], kw))   # [I, K]
    scale, dd, d_f = _hard_item_radiation(edges, lk, radar, m_i, e_i, w, s, d, st, sb, k0, tx_ant, rx_ant, links,
                                          polarisation)
    coef = scale * amp * torch.exp(-1j * (dd + d_f)[:, None] * k0[None])
    return lk[m_i], edges.gauss_a[e_i], edges.gauss_a[fold], coef


def edge_reflection(mats, freq_hz: torch.Tensor) -> torch.Tensor:
    """rho [N, K] of each material: -R_TE at normal incidence times sqrt(1 - S^2) (1 for a perfect conductor)."""
    spec = specular_share(mats.scattering)[:, None]
    return -mats.normal_reflection(freq_hz) * spec


def edge_field(terms: EdgeTerms, material_of_gaussian: torch.Tensor, mats) -> torch.Tensor:
    """Edge field [M, K] complex of the items, for materials `mats` (physical.MaterialValues)."""
    rho = edge_reflection(mats, terms.freq_hz)
    r = 0.5 * (rho[material_of_gaussian[terms.gauss_a]] + rho[material_of_gaussian[terms.gauss_b]])
    out = torch.zeros((terms.num_links, terms.freq_hz.numel()), dtype=torch.complex128)
    return out.index_add(0, terms.link, terms.coef * r)


def aggregate_edges(terms: EdgeTerms, material_of_gaussian: torch.Tensor, num_materials: int) -> torch.Tensor:
    """[M, N, K] complex: the items' coefficients summed per (link, material), half to each face's material,
    so that the edge field is sum_n agg[:, n] rho[n] (edge_reflection)."""
    m, k = terms.num_links, int(terms.freq_hz.numel())
    out = torch.zeros((m * num_materials, k), dtype=torch.complex128)
    for g in (terms.gauss_a, terms.gauss_b):
        out.index_add_(0, terms.link * num_materials + material_of_gaussian[g], 0.5 * terms.coef)
    return out.reshape(m, num_materials, k)
