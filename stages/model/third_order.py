"""Third-order (triple-bounce) specular terms by images over planar patches (docs/physics.md section 8.7.1).

A trihedral corner reflector's flash is a triple bounce: Tx -> plane A -> plane B -> surfel m of plane C
-> Rx. With the image Tx_A of the transmitter in plane A and the image Tx_AB of Tx_A in plane B, the
third bounce is the surfel physical optics of C lit by Tx_AB, the polarisation carried through both
specular reflections:

    S_3 = sum_(A, B, m in C) j sqrt(G_T G_R) P_m A_m F_m(k) V exp(-j k (d_i'' + d_o)) / (4 pi d_i'' d_o),
    P_m = sum_XY R_X(A, theta_A) R_Y(B, theta_B) (sum_Z b_XYZ R_Z(C, theta_m) + b_XY0)

d_i'' = |Tx_AB - x_m| (the length of Tx -> A -> B -> m); the segment Tx_AB -> x_m crosses plane B at
c_B, and the segment Tx_A -> c_B crosses plane A at c_A; theta_A, theta_B the incidence angles there;
b_XYZ, b_XY0 the physical-optics factors of m lit by the wave that A and B reflect in their X and Y
(TE/TM) parts (second_order.bounce_factors, the double bounce's with one more reflection). A term exists
only when both crossings lie inside their patch's aperture (`second_order.aperture_hits`, the
boundary the double bounce and the edge waves use) and on a surfel's cell. Materials: those of the
surfels whose cells hold c_A and c_B (each reflection scaled by sqrt(1 - S^2), as in the double
bounce), and of m. V = V(Tx -> the surfel of A at c_A) V(Rx -> m), the first-order pairs' lit states;
the leg A -> B is not traced (the surfel of B at c_B is chosen among those whose cell holds it, lit
from the antenna or not: a corner's plates shadow parts of each other from the radar that the wave
reflected by A reaches). Co-located antennas only (monostatic radar), as the double bounce.

Triples (`bounce_triples`): corners, ordered (A, B, C) of three distinct patches of which every two are
dihedral partners (`second_order.dihedral_partners`; a trihedral, the inner corner of stacked bricks), and
returns, (A, B, A) of every partner pair: the ray that A turns onto B at normal incidence comes back the
way it went (an acute wedge's flash, on a 60-degree wedge's bisector; C = A is the same construction).
That bounds the cost; triple bounces over planes that are not pairwise partners (parallel or far
apart) are left out.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from .antenna_patterns import AntennaPattern
from .occlusion import FrozenGeometry
from .link_set import LinkSet

from .edges import patch_coverage_of
from .link_rows import renumber_links
from .second_order import (Patches, _in_cell, _unit, aperture_hits, bounce_factors, dihedral_partners,
                           image_coef, mirror_points, patch_extents, segment_crossing)
from .surfels import COPLANAR_M, covariance

NUM_FACTORS = 12   # bounce_factors of three planes: 8 products R_X(A) R_Y(B) R_Z(C), then 4 of R_X(A) R_Y(B)
TRIPLE_BLOCK = 1 << 21   # (ordered triple, link) entries per block of the pre-test (bounded memory)
CANDIDATE_BLOCK = 1 << 20   # (triple, link, surfel of C) rows tested at once (bounded memory)
RETURN_COS = 0.02   # returns (A, B, A) need a wedge under 89 degrees: nearer a right angle the ray grazes A


@dataclass
class TripleBounce:
    """Triple-bounce items: I items (link, patch A, patch B, surfel m of C), stored without frequency.

    link [I]; gauss [I, 3]: the surfels at c_A and c_B (their materials) and m; cos [I, 3] the incidence
    cosines at A, B and m; pol [I, 12]: `second_order.bounce_factors` of the three planes; amp [I]:
    sqrt(G_T G_R) V A_m / (4 pi d_i'' d_o) (A_m in m^2, distances in m); q_cell [I, 2] m: m's cell times
    w_i + w_o (its footprint factor); path_m [I]: d_i'' + d_o. The coefficient at any frequency is
    `coef(k0)`: a band's frequency chunks need no slicing of the items."""

    num_links: int
    link: torch.Tensor
    gauss: torch.Tensor
    cos: torch.Tensor
    pol: torch.Tensor
    amp: torch.Tensor
    q_cell: torch.Tensor
    path_m: torch.Tensor

    @property
    def num(self) -> int:
        return int(self.link.numel())

    def coef(self, k0: torch.Tensor) -> torch.Tensor:
        """[I, K] complex at wavenumbers k0 [K] rad/m: everything but the polarisation factors, the
        reflection coefficients and the sqrt(1 - S^2) factors (`second_order.image_coef`)."""
        return image_coef(self.amp, self.q_cell, self.path_m, k0)

    def select_links(self, rows) -> "TripleBounce":
        rows, keep, new_link = renumber_links(self.link, self.num_links, rows)
        return TripleBounce(int(rows.numel()), new_link, self.gauss[keep], self.cos[keep], self.pol[keep],
                            self.amp[keep], self.q_cell[keep], self.path_m[keep])


def empty_triple_bounce(num_links: int) -> TripleBounce:
    z = torch.zeros(0, dtype=torch.int64)
    f = torch.zeros(0, dtype=torch.float64)
    return TripleBounce(num_links, z, torch.zeros((0, 3), dtype=torch.int64), torch.zeros((0, 3), dtype=torch.float64),
                        torch.zeros((0, NUM_FACTORS), dtype=torch.float64), f, torch.zeros((0, 2), dtype=torch.float64), f)


def bounce_triples(partners: list[list[int]]) -> list[tuple[int, int, int]]:
    """Ordered triples (A, B, C) of patches a triple bounce may visit in turn (partners[p]: the dihedral
    partners of patch p, a symmetric relation): corners, three distinct patches of which every two are
    partners (each corner in its 6 orders), and returns (A, B, A) of every partner pair (both orders: the
    ray that A turns onto B at normal incidence comes back the way it went; an acute wedge's flash)."""
    sets = [set(p) for p in partners]
    out = []
    for a, pa in enumerate(sets):
        for b in pa:
            out.append((a, b, a))
            for c in pa & sets[b]:
                if c != a and c != b:
                    out.append((a, b, c))
    return sorted(out)


def build_triple_bounce(geom: FrozenGeometry, links: LinkSet, tx_ant: AntennaPattern, rx_ant: AntennaPattern,
                        patches: Patches, areas_m2: torch.Tensor, cells: torch.Tensor, vis_lookup,
                        polarisation: str = "V", colocated_tol_m: float = 0.01) -> TripleBounce:
    """Triple-bounce items of every link (see the module docstring); arguments as
    `second_order.build_double_bounce` (vis_lookup(link, gauss) -> V of the first-order pairs).

    The candidates (ordered triple, link, surfel m of C) are tested as flat arrays, cheapest test first
    (`_open_corners` per triple and link, then the crossing of B's plane near B and m's lit state, then
    the apertures): a corner-rich object has 10^5 ordered triples, of which few carry items."""
    colocated = ((links.tx_m - links.rx_m).norm(dim=-1) < colocated_tol_m).numpy()
    if patches.area.size < 2 or not colocated.any():
        return empty_triple_bounce(links.num)
    if patches.corners is None:   # geometry only: found once per set of patches (prediction's link chunks reuse it)
        patches.corners = _corners(geom, patches, areas_m2, cells)
    triples, refl = patches.corners
    if not len(triples):
        return empty_triple_bounce(links.num)
    lo, hi = refl.lo, refl.hi
    lit = _lit_patches(links.num, patches, vis_lookup)
    tx = links.tx_m.numpy()
    parts = []
    per_block = max(1, TRIPLE_BLOCK // links.num)
    for a in range(0, len(triples), per_block):
        block = triples[a:a + per_block]
        ti, li = np.nonzero(_open_corners(block, patches, lo, hi, tx, colocated, lit))     # [Q]
        step = max(1, CANDIDATE_BLOCK // max(int(refl.size[block[:, 2]].max()), 1))
        for q in range(0, len(ti), step):
            item = _corner_items(geom, links, block[ti[q:q + step]], li[q:q + step], refl, vis_lookup, tx_ant, rx_ant,
                                 polarisation)
            if item is not None:
                parts.append(item)
    if not parts:
        return empty_triple_bounce(links.num)
    cat = {k: torch.cat([p[k] for p in parts]) for k in parts[0]}
    return TripleBounce(links.num, cat["link"], cat["gauss"], cat["cos"], cat["pol"], cat["amp"], cat["q_cell"],
                        cat["path"])


def _corners(geom: FrozenGeometry, patches: Patches, areas_m2: torch.Tensor, cells: torch.Tensor):
    """(ordered triples [T, 3] of `bounce_triples`, the patches as `_Reflectors` with the side extents lo, hi
    of the pairs the triples use): everything of the triple bounce that depends on the geometry alone."""
    x = geom.means.numpy()
    radius, reach = patch_extents(patches, x, areas_m2)
    triples = np.asarray(bounce_triples(dihedral_partners(patches, radius)), dtype=np.int64).reshape(-1, 3)
    triples = triples[_acute_or_unknown(triples, patches, x)]
    refl = _Reflectors(geom, patches, areas_m2, cells, radius, reach)
    if len(triples):
        n = len(patches.members)
        ends = np.unique(np.concatenate([triples[:, 0] * n + triples[:, 1], triples[:, 1] * n + triples[:, 0],
                                         triples[:, 1] * n + triples[:, 2], triples[:, 2] * n + triples[:, 1]]))
        refl.lo, refl.hi = _side_extents(patches, x, cells.numpy(), np.stack([ends // n, ends % n], 1))
    return triples, refl


def _acute_or_unknown(abc: np.ndarray, patches: Patches, x: np.ndarray, tol: float = COPLANAR_M) -> np.ndarray:
    """[T] bool: keep the corners, and the returns (A, B, A) unless A and B make a wedge of 89 degrees or
    more. A return needs the ray that A turns onto B at normal incidence: with each normal turned towards
    the other patch (B's surfel centres x [G, 3] m all on one side of A's plane and A's of B's), that ray
    meets A from inside the wedge only when the inner angle is acute (n_A . n_B < 0); a right-angled
    dihedral's return would run along A. Patches whose centres straddle each other's plane are kept
    (the crossings decide)."""
    keep = np.ones(len(abc), dtype=bool)
    normal, point = patches.normal, patches.point
    def side(p, q):             # +1 / -1: q's centres all above / below p's plane; 0: they straddle it
        off = (x[patches.members[q]] - point[p]) @ normal[p]
        return 1.0 if off.min() > -tol else -1.0 if off.max() < tol else 0.0
    for t in np.flatnonzero(abc[:, 0] == abc[:, 2]):
        a, b = abc[t, :2]
        s_ab, s_ba = side(a, b), side(b, a)
        keep[t] = s_ab == 0 or s_ba == 0 or float(normal[a] @ normal[b]) * s_ab * s_ba < -RETURN_COS
    return keep


class _Reflectors:
    """The patches as reflectors: normal [P, 3], point [P, 3] m, radius [P] m (members' farthest distance from
    point), reach [P] m (largest surfel's side), size [P] members, flat [sum] members patch after patch from
    start [P]; each patch's cKDTree of its members' means and aperture (edges.patch_coverage_of), made when
    first asked for."""

    def __init__(self, geom, patches: Patches, areas_m2: torch.Tensor, cells: torch.Tensor, radius: np.ndarray,
                 reach: np.ndarray):
        self.geom, self.patches, self.cells = geom, patches, cells
        self.x = geom.means.numpy()
        self.normal, self.point, self.radius, self.reach = patches.normal, patches.point, radius, reach
        self.areas_m2 = areas_m2
        self.size = np.array([len(m) for m in patches.members])
        self.start = np.concatenate([[0], np.cumsum(self.size)[:-1]])
        self.flat = np.concatenate(patches.members)
        self._trees, self._cov = {}, None
        self.lo = self.hi = None        # [P, P] m: _side_extents of the pairs in use, set by `_corners`

    def tree(self, p: int):
        from scipy.spatial import cKDTree

        if p not in self._trees:
            self._trees[p] = cKDTree(self.x[self.patches.members[p]])
        return self._trees[p]

    def aperture(self, p: int):
        if self._cov is None:
            self._cov = covariance(self.geom.log_scales, self.geom.rotations).numpy()
        return patch_coverage_of(self.patches, p, self.x, self._cov, self.cells.numpy())[0]

    def crossing(self, p: np.ndarray, src: np.ndarray, dst: np.ndarray):
        """(valid [N] bool, c [N, 3] m, near [N, 4] surfel indices, on_cell [N, 4] bool tensor): where the
        segments src -> dst [N, 3] m cross the plane of patch p [N] inside its aperture
        (second_order.aperture_hits), and the candidate surfels for the cell that holds the crossing
        (second_order._in_cell; padded with the nearest where a patch has fewer than 4)."""
        t, c = segment_crossing(src, dst, self.point[p], self.normal[p])
        valid = (t > 0) & (t < 1) & (np.linalg.norm(c - self.point[p], axis=1) <= self.radius[p] + self.reach[p])
        near = np.zeros((len(c), 4), dtype=np.int64)
        for q in np.unique(p[valid]):
            sel = np.flatnonzero(valid & (p == q))
            members = self.patches.members[q]
            hit, nv = aperture_hits(c[sel], self.tree(q), members, float(self.reach[q]), self.aperture(q))
            near[sel] = members[np.concatenate([nv, np.repeat(nv[:, :1], 4 - nv.shape[1], 1)], 1)]
            valid[sel] = hit
        g = torch.as_tensor(near)
        on_cell = _in_cell(torch.as_tensor(c)[:, None], self.geom.means[g], self.cells[g]) & torch.as_tensor(valid)[:, None]
        return valid, c, near, on_cell


def _lit_patches(num_links: int, patches: Patches, vis_lookup, block: int = 1 << 22) -> np.ndarray:
    """[M, P] bool: patch p has a surfel lit from link m's antenna (the first-order pairs' lit states)."""
    ids = torch.as_tensor(patches.id)
    member = torch.nonzero(ids >= 0).flatten()
    out = torch.zeros((num_links, len(patches.members)), dtype=torch.float64)
    step = max(1, block // max(int(member.numel()), 1))
    for a in range(0, num_links, step):
        rows = torch.arange(a, min(num_links, a + step))
        v = (vis_lookup(rows[:, None], member[None]) > 0).double()              # [m, G']
        out[rows] = torch.zeros((len(rows), out.shape[1]), dtype=torch.float64).index_add_(1, ids[member], v)
    return (out > 0).numpy()


def _side_extents(patches: Patches, x: np.ndarray, cells: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) [P, P] m: how far below and above patch p's plane patch q reaches along p's normal, for the
    pairs (p, q) [N, 2] asked for (elsewhere 0): its members' means x [G, 3] m each widened by its cell's
    extent along that normal (cells [G, 2, 3] m, half-side axes: the aperture reaches the patch's true
    edge, about half a cell past the outermost means)."""
    n = len(patches.members)
    lo, hi = np.zeros((n, n)), np.zeros((n, n))
    for p in np.unique(pairs[:, 0]):
        off = (x - patches.point[p]) @ patches.normal[p]                          # [G]
        ext = np.abs(cells @ patches.normal[p]).sum(1)                            # [G]
        for q in pairs[pairs[:, 0] == p, 1]:
            m = patches.members[q]
            lo[p, q], hi[p, q] = (off[m] - ext[m]).min(), (off[m] + ext[m]).max()
    return lo, hi


def _open_corners(abc: np.ndarray, patches: Patches, lo: np.ndarray, hi: np.ndarray, tx: np.ndarray,
                  colocated: np.ndarray, lit: np.ndarray, tol: float = COPLANAR_M) -> np.ndarray:
    """[T, M] bool: the ordered triples abc [T, 3] that link m can use (lo, hi from `_side_extents`; tx [M, 3] m;
    colocated [M]; lit [M, P] from `_lit_patches`): A and C have lit surfels, and the reflections at A and B
    have both legs on one side of their planes with the patches there: B reaches Tx's side of A (c_B lies
    there), A and C reach Tx_A's side of B (c_A and m lie there). A convex corner (each face behind the
    others' planes, up to its true edge) fails the first; a patch reaching less than `tol` past a plane
    does not count. Necessary conditions only: the crossings decide (`_corner_items`)."""
    def has(p, q, side):            # [T, M]: patch q reaches `side` of patch p's plane
        return np.where(side > 0, hi[p, q][:, None] > tol, lo[p, q][:, None] < -tol) & (np.abs(side) > 1e-9)

    a, b, c = abc.T
    nrm, pt = patches.normal, patches.point
    side_tx = tx @ nrm.T - (pt * nrm).sum(1)[None]                                # [M, P]
    s_a = side_tx[:, a].T                                                         # [T, M] Tx relative to A
    s_b = side_tx[:, b].T - 2.0 * s_a * (nrm[a] * nrm[b]).sum(1)[:, None]        # Tx_A relative to B
    return colocated[None] & lit[:, a].T & lit[:, c].T & has(a, b, s_a) & has(b, a, s_b) & has(b, c, s_b)


def _may_cross(refl: _Reflectors, pb: np.ndarray, pc: np.ndarray, src: np.ndarray) -> np.ndarray:
    """[Q] bool: a segment from src [Q, 3] m (an image, on the far side of patch B's plane from the points
    of patch C that count) to some point of C can cross B's plane within B's radius and reach of its
    centre; a conservative test per candidate before the rows over C's members (B, C: any two patches).
    With in-plane parts q (src) and r (C's points: within rho, C's radius and reach, of its centre's r0)
    relative to B's centre, and offsets s, h from the plane, the crossing is q + lambda (r - q),
    lambda = s / (s + h) in [lambda_lo, lambda_hi] over C's offsets (refl.lo, refl.hi): at least the
    distance from the origin to the segment q + lambda (r0 - q) less lambda_hi rho from B's centre."""
    nb, pt = refl.normal[pb], refl.point[pb]
    off = ((src - pt) * nb).sum(1)                                      # the double image's offset
    s = np.abs(off)
    lo = np.where(off < 0, refl.lo[pb, pc], -refl.hi[pb, pc])           # C's offsets on the far side
    hi = np.where(off < 0, refl.hi[pb, pc], -refl.lo[pb, pc])
    lam_lo = s / (s + np.maximum(hi, 1e-12))
    lam_hi = s / (s + np.maximum(lo, 0.0))
    q = src - pt - off[:, None] * nb
    r0 = refl.point[pc] - pt
    d = r0 - (r0 * nb).sum(1)[:, None] * nb - q
    lam = np.clip(-(q * d).sum(1) / np.maximum((d * d).sum(1), 1e-300), lam_lo, lam_hi)
    dist = np.linalg.norm(q + lam[:, None] * d, axis=1)
    return (hi > 0) & (dist - lam_hi * (refl.radius[pc] + refl.reach[pc]) <= refl.radius[pb] + refl.reach[pb])


def _corner_items(geom, links, abc, link, refl: _Reflectors, vis_lookup, tx_ant, rx_ant, polarisation):
    """Items of the candidates (ordered triple abc [Q, 3], link [Q]) over every surfel m of C: the double
    image Tx_AB's segment to m crosses B inside its aperture at c_B, Tx_A's segment to c_B crosses A inside
    its aperture at c_A, m is lit from Rx and the surfel of A at c_A from Tx."""
    pa, pb, pc = abc.T
    tx = links.tx_m.numpy()[link]
    tx_a = mirror_points(tx, refl.point[pa], refl.normal[pa])                # image in A
    tx_ab = mirror_points(tx_a, refl.point[pb], refl.normal[pb])             # ... in B
    near = _may_cross(refl, pb, pc, tx_ab) & _may_cross(refl, pa, pb, tx_a)   # Tx_AB -> C across B, Tx_A -> B across A
    abc, link, pa, pb, pc, tx, tx_a, tx_ab = (v[near] for v in (abc, link, pa, pb, pc, tx, tx_a, tx_ab))
    if not len(abc):
        return None
    # every surfel m of C: rows (candidate e, surfel m), m the k-th member of C's run in refl.flat
    size = refl.size[pc]
    e = np.repeat(np.arange(len(abc)), size)
    k = np.arange(len(e)) - np.repeat(np.cumsum(size) - size, size)
    m = refl.flat[refl.start[pc][e] + k]
    xm = refl.x[m]
    # the segment Tx_AB -> m crosses B's plane near B (m on Tx_A's side of B), before any lookup
    t, c = segment_crossing(tx_ab[e], xm, refl.point[pb[e]], refl.normal[pb[e]])
    near_b = (t > 0) & (t < 1) & (np.linalg.norm(c - refl.point[pb[e]], axis=1) <= refl.radius[pb[e]] + refl.reach[pb[e]])
    e, m, xm = e[near_b], m[near_b], xm[near_b]
    if not len(e):
        return None
    v_c = vis_lookup(torch.as_tensor(link[e]), torch.as_tensor(m))       # the last leg lit: V(Rx -> m)
    keep = (v_c > 0).numpy()
    e, m, xm, v_c = e[keep], m[keep], xm[keep], v_c[torch.as_tensor(keep)]
    if not len(e):
        return None
    valid, c_b, near, on_cell = refl.crossing(pb[e], tx_ab[e], xm)
    # the surfel of B whose cell holds c_B, nearest first (its material; the leg A -> B is not traced)
    g_b = near[np.arange(len(near)), torch.argmax(on_cell.to(torch.int8), 1).numpy()]
    valid &= on_cell.any(1).numpy()
    e, m, xm, c_b, g_b, v_c = e[valid], m[valid], xm[valid], c_b[valid], g_b[valid], v_c[torch.as_tensor(valid)]
    if not len(e):
        return None
    valid, c_a, near, on_cell = refl.crossing(pa[e], tx_a[e], c_b)
    # the lit surfel of A nearest c_A whose cell holds it (as the double bounce's first reflection)
    lk = link[e]
    v_near = vis_lookup(torch.as_tensor(lk)[:, None], torch.as_tensor(near))
    v_near = torch.where(on_cell, v_near, torch.zeros_like(v_near))
    v_a, pick = v_near.max(1)
    g_a = near[np.arange(len(near)), pick.numpy()]
    v = v_a * v_c
    keep = (v > 1e-6).numpy() & valid
    if not keep.any():
        return None
    e, m, c_a, c_b, g_a, g_b, lk, v = e[keep], m[keep], c_a[keep], c_b[keep], g_a[keep], g_b[keep], lk[keep], \
        v[torch.as_tensor(keep)]
    src = torch.as_tensor(tx_ab[e])
    xm_t = geom.means[torch.as_tensor(m)]
    to_src = src - xm_t
    d_i = to_src.norm(dim=-1)
    w_i = to_src / d_i[:, None]
    to_rx = links.rx_m[torch.as_tensor(lk)] - xm_t
    d_o = to_rx.norm(dim=-1)
    w_o = to_rx / d_o[:, None]
    nc = geom.normals[torch.as_tensor(m)]
    nc = nc * torch.where((w_i * nc).sum(-1, keepdim=True) >= 0, 1.0, -1.0)   # facing the wave
    cos_c, cos_o = (w_i * nc).sum(-1), (w_o * nc).sum(-1)
    sel = ((cos_c > 1e-6) & (cos_o > 1e-6)).numpy()
    if not sel.any():
        return None
    idx = torch.as_tensor(np.flatnonzero(sel))
    e, m, c_a, c_b, g_a, g_b, lk = e[sel], m[sel], c_a[sel], c_b[sel], g_a[sel], g_b[sel], lk[sel]
    v, nc, w_i, w_o, d_i, d_o, cos_c = (q.index_select(0, idx) for q in (v, nc, w_i, w_o, d_i, d_o, cos_c))
    ca_t, cb_t = torch.as_tensor(c_a), torch.as_tensor(c_b)
    i_1 = _unit(ca_t - torch.as_tensor(tx[e]))                            # Tx -> c_A
    i_2 = _unit(cb_t - ca_t)                                              # c_A -> c_B: i_1 mirrored in A
    n_a = _facing(torch.as_tensor(refl.normal[pa[e]]), i_1)
    n_b = _facing(torch.as_tensor(refl.normal[pb[e]]), i_2)
    cos_a, cos_b = -(i_1 * n_a).sum(-1), -(i_2 * n_b).sum(-1)
    lt = torch.as_tensor(lk)
    g_t = tx_ant.gain(i_1, links.tx_axis[lt])
    g_r = rx_ant.gain(-w_o, links.rx_axis[lt])
    mt = torch.as_tensor(m)
    q_cell = torch.einsum("pcj,pj->pc", refl.cells[mt], w_i + w_o)
    amp = torch.sqrt(g_t * g_r) * v * refl.areas_m2[mt] / (4 * math.pi * d_i * d_o)
    return {"link": lt, "gauss": torch.as_tensor(np.stack([g_a, g_b, m], 1)),
            "cos": torch.stack([cos_a, cos_b, cos_c], 1),
            "pol": bounce_factors([i_1, i_2, -w_i], [n_a, n_b, nc], w_o, polarisation),
            "amp": amp, "q_cell": q_cell, "path": d_i + d_o}


def _facing(n: torch.Tensor, i: torch.Tensor) -> torch.Tensor:
    """[I, 3]: plane normals n [I, 3] turned to face waves travelling along i [I, 3]."""
    return n * torch.where((i * n).sum(-1, keepdim=True) < 0, 1.0, -1.0)
