"""Second-order (double-bounce) specular terms by images over planar patches (docs/physics.md section 8.7).

A dihedral's flash is a double bounce: Tx -> plane A -> surfel m of plane B -> Rx. With the image
Tx_A of the transmitter in plane A, the second bounce is the surfel physical optics of B lit by
Tx_A, with the polarisation carried through both reflections:

    S_2 = sum_(A, m in B) j sqrt(G_T G_R) P_m A_m F_m(k) V exp(-j k (d_i' + d_o)) / (4 pi d_i' d_o),
    P_m = sum_X R_X(A, theta_A) (sum_Y b_XY R_Y(B, theta_B) + b_X0)

d_i' = |Tx_A - x_m| (the length of Tx -> A -> m), theta_A the incidence angle at the crossing point c
of the segment Tx_A -> x_m with plane A; b_XY, b_X0 the physical-optics factors of m lit by the wave
that A reflects in its X (TE/TM) part (`second_bounce_factors`): the radiation of m's PO currents
J = n x H, M = -n x E (incident plus reflected fields) toward Rx. Where m reflects its wave
specularly towards Rx (a corner reflector's flash), b_XY = c_XY cos_i' (the polarisation chain
`polarisation_chain` times the obliquity) and b_X0 = 0; away from it the incident field's own
currents radiate too (b_X0, independent of B's material: (cos_o - cos_i') / 2 for a wave in B's plane
of incidence), and the symmetric obliquity (cos_i' + cos_o) / 2 of the single bounce would leave
them out (a double bounce seen far from B's specular direction would come out low). A term exists only when c
lies inside A's boundary, the level line at half A's interior coverage (`edges.patch_coverage`, the
boundary the edge waves use): a hard aperture at A's true edge, as the geometric-optics
first bounce of the PO solver's ray tubes; A's edge diffraction is left out, and a crossing past A's
edge, as at a convex edge, makes none. Its material and lit state are those of the lit surfel of A
whose cell holds c (within CELL_MARGIN of its sides: the cells of a triangle tiling leave gaps, which
the margin closes; as an aperture the widened cells would reach up to half a half-side past A's edge,
and light a strip of B beyond the reflected beam's shadow boundary). Tx and m are
on the same side of A, Tx_A and Rx on the same side of B, and both legs are lit: V = V(Tx -> that
surfel of A) V(Rx -> m), looked up in the first-order pairs. That lookup makes the term exact for
co-located antennas (monostatic radar); links with separated antennas get no second order here
(rooms need per-leg tracing).

Planar patches: surfels joined when neighbours (within `join_factor` spacings), with normals within
`PARALLEL_COS` and on the same plane; patches smaller than `min_patch_area_m2` carry no double
bounce (a bounce off a patch much smaller than a wavelength is weak and is not specular). Pairs of
patches are kept when they can form a corner reflector (`dihedral_partners`): that bounds the cost
on objects with many faces, and leaves out double bounces between patches far apart or at
shallow angles (weak for a co-located radar).
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np
import torch

from .antenna_patterns import AntennaPattern
from .occlusion import FrozenGeometry
from .link_set import LinkSet

from .edges import patch_coverage_of
from .link_rows import renumber_links
from rfir_core.physics.materials import C0
from rfir_core.physics.polarisation import antenna_polarisation, reflection_basis
from .plane_merge import merge_coplanar, offset_scatter_m
from .surfels import COPLANAR_M, covariance, footprint_factor

PARALLEL_COS = 0.98     # normals this close, offsets along them below COPLANAR_M: one plane (such patches form no dihedral)
DIHEDRAL_COS = 0.5      # patches whose normals are 60-120 degrees apart can form a corner reflector
NORMAL_TOL = 1e-6       # patch normals are surfel averages: a wedge of exactly 60 degrees must not depend on rounding
CELL_MARGIN = 0.5       # a crossing within half a half-side past a cell is on it (the cells of a triangle tiling leave gaps;
                        # the aperture's edge is the patch's boundary, edges.patch_coverage, not the cells')


@dataclass
class Patches:
    """Planar patches: id [G] (-1: in no patch used for double bounces), normal [P, 3], point [P, 3],
    area [P] m^2, members: list of surfel index arrays; coverage: each patch's edges.patch_coverage_of, kept
    once computed; corners: the triple bounce's (third_order), kept once found."""

    id: np.ndarray
    normal: np.ndarray
    point: np.ndarray
    area: np.ndarray
    members: list
    coverage: dict = field(default_factory=dict)
    corners: object = None      # third_order's candidate corners and reflectors, kept once found
    merge_tol_m: float = 0.0    # RMS offset of the fitted planes (plane_merge; 0: neighbours were joined)


def planar_patches(geom: FrozenGeometry, areas_m2: torch.Tensor, labels: torch.Tensor | None = None,
                   min_patch_area_m2: float = 2e-3, join_factor: float = 1.6,
                   coplanar_m: float = COPLANAR_M, merge_scatter_factor: float = 0.0) -> Patches:
    """Group surfels into planar patches (union-find over neighbour pairs on one plane, one label);
    coplanar_m: the largest offset along the normal between neighbours of one plane. merge_scatter_factor > 0:
    where that many times the Gaussians' scatter about their local planes exceeds coplanar_m (Gaussians from
    photos), planes are fitted instead: surfels merged into patches while the plane of each union holds them
    to that RMS offset (plane_merge; the tolerance is kept in Patches.merge_tol_m, 0 when neighbours were
    joined)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    x = geom.means.numpy()
    n = geom.normals.numpy()
    a = areas_m2.numpy()
    g = len(x)
    if g == 0:
        return Patches(np.zeros(0, int), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), [])
    radius = join_factor * 2.0 * float(np.median(np.sqrt(a)))
    pairs = cKDTree(x).query_pairs(radius, output_type="ndarray")
    i, j = pairs[:, 0], pairs[:, 1]
    if labels is not None:
        lab = labels.numpy()
        one_label = lab[i] == lab[j]
        i, j = i[one_label], j[one_label]
    cos = (n[i] * n[j]).sum(1)
    parallel = np.abs(cos) >= PARALLEL_COS
    merge_tol_m = 0.0
    if merge_scatter_factor > 0:     # the scatter about local planes from same-facing neighbours (plane_merge)
        merge_tol_m = merge_scatter_factor * offset_scatter_m(x, i, j, cos >= PARALLEL_COS)
    if merge_tol_m > coplanar_m:
        # scattered wider than neighbours can be joined by: one stray pair would join two surfaces, and the
        # neighbour offsets of one surface exceed coplanar_m; every Gaussian starts alone and planes are fitted
        comp = merge_coplanar(np.arange(g), x, n, a, i, j, PARALLEL_COS, merge_tol_m)
    else:
        merge_tol_m = 0.0
        same = parallel & (np.abs((n[i] * (x[j] - x[i])).sum(1)) < coplanar_m)
        graph = coo_matrix((np.ones(int(same.sum())), (i[same], j[same])), shape=(g, g))
        _, comp = connected_components(graph, directed=False)
    ids = np.full(g, -1)
    normals, points, areas, members = [], [], [], []
    for c in np.unique(comp):
        idx = np.flatnonzero(comp == c)
        area = float(a[idx].sum())
        if area < min_patch_area_m2:
            continue
        w = a[idx] / area
        nn = n[idx] * np.sign((n[idx] * n[idx[0]]).sum(1))[:, None]
        nrm = (w[:, None] * nn).sum(0)
        ids[idx] = len(normals)
        normals.append(nrm / np.linalg.norm(nrm))
        points.append((w[:, None] * x[idx]).sum(0))
        areas.append(area)
        members.append(idx)
    return Patches(ids, np.asarray(normals).reshape(-1, 3), np.asarray(points).reshape(-1, 3), np.asarray(areas),
                   members, merge_tol_m=merge_tol_m)


@dataclass
class DoubleBounce:
    """Double-bounce terms: I items (link, first patch A, surfel m of B). Gamma enters per step.

    link [I]; gauss_a [I] (the surfel of A nearest the crossing: its material), gauss_b [I] (m);
    cos_a, cos_b [I] incidence cosines at A and B; pol [I, 6]: the physical-optics factors of the
    products R_X(A) R_Y(B) for XY = (TE, TE), (TE, TM), (TM, TE), (TM, TM), then of R_TE(A) and R_TM(A)
    alone (`second_bounce_factors`); coef [I, K] complex: everything but these factors, the reflection
    coefficients and the sqrt(1 - S^2) factors."""

    num_links: int
    link: torch.Tensor
    gauss_a: torch.Tensor
    gauss_b: torch.Tensor
    cos_a: torch.Tensor
    cos_b: torch.Tensor
    pol: torch.Tensor
    coef: torch.Tensor
    freq_hz: torch.Tensor

    @property
    def num(self) -> int:
        return int(self.link.numel())

    def select_links(self, rows) -> "DoubleBounce":
        rows, keep, new_link = renumber_links(self.link, self.num_links, rows)
        return DoubleBounce(int(rows.numel()), new_link, self.gauss_a[keep], self.gauss_b[keep],
                            self.cos_a[keep], self.cos_b[keep], self.pol[keep], self.coef[keep], self.freq_hz)


def empty_double_bounce(num_links: int, freq_hz: torch.Tensor) -> DoubleBounce:
    z = torch.zeros(0, dtype=torch.int64)
    f = torch.zeros(0, dtype=torch.float64)
    return DoubleBounce(num_links, z, z, z, f, f, torch.zeros((0, 6), dtype=torch.float64),
                        torch.zeros((0, int(freq_hz.numel())), dtype=torch.complex128), freq_hz.double())


def build_double_bounce(geom: FrozenGeometry, links: LinkSet, tx_ant: AntennaPattern, rx_ant: AntennaPattern,
                        patches: Patches, areas_m2: torch.Tensor, cells: torch.Tensor, vis_lookup,
                        polarisation: str = "V", colocated_tol_m: float = 0.01) -> DoubleBounce:
    """Double-bounce items of every link (see the module docstring).

    vis_lookup(link, gauss) -> V: visibility of a surfel from the link's antenna (the first-order
    pairs'; 0 where the surfel is not lit), for index tensors of any broadcastable shapes."""
    from scipy.spatial import cKDTree

    freq = links.freq_hz.double()
    k0 = 2 * math.pi * freq / C0
    colocated = ((links.tx_m - links.rx_m).norm(dim=-1) < colocated_tol_m).numpy()
    if patches.area.size < 2 or not colocated.any():
        return empty_double_bounce(links.num, freq)
    x = geom.means.numpy()
    trees = [cKDTree(x[m]) for m in patches.members]
    radius, reach = patch_extents(patches, x, areas_m2)
    cov = covariance(geom.log_scales, geom.rotations).numpy()
    cell_axes = cells.numpy()                                             # [G, 2, 3] half-side axes
    parts = []
    for pa, partners in enumerate(dihedral_partners(patches, radius)):
        if not partners:
            continue
        na, pa_pt = patches.normal[pa], patches.point[pa]
        mb = np.concatenate([patches.members[pb] for pb in partners])
        xb = x[mb]                                                        # [B, 3]
        side_b = (xb - pa_pt) @ na                                        # B's surfels relative to plane A
        ma = patches.members[pa]
        aperture, _ = patch_coverage_of(patches, pa, x, cov, cell_axes)
        item = _pair_items(geom, links, colocated, na, pa_pt, mb, xb, side_b, trees[pa], ma, reach[pa], vis_lookup,
                           tx_ant, rx_ant, cells, areas_m2, k0, polarisation, patches.point[pa], radius[pa], aperture)
        if item is not None:
            parts.append(item)
    if not parts:
        return empty_double_bounce(links.num, freq)
    cat = {k: torch.cat([p[k] for p in parts]) for k in parts[0]}
    return DoubleBounce(links.num, cat["link"], cat["ga"], cat["gb"], cat["cos_a"], cat["cos_b"], cat["pol"],
                        cat["coef"], freq)


def patch_extents(patches: Patches, x: np.ndarray, areas_m2: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
    """(radius [P] m: each patch's members' farthest distance from its point, reach [P] m: its largest surfel's
    side) from the Gaussians' means x [G, 3] m and areas [G] m^2: how far a crossing of its plane may lie."""
    area = areas_m2.numpy()
    radius = np.array([np.linalg.norm(x[m] - patches.point[i], axis=1).max() for i, m in enumerate(patches.members)])
    return radius, np.array([float(np.sqrt(area[m].max())) for m in patches.members])


def dihedral_partners(patches: Patches, radius: np.ndarray) -> list[list[int]]:
    """For each patch A, the patches B that can form a dihedral with it: normals between 60 and 120
    degrees apart (the monostatic double bounce is a corner reflector's; nearly parallel planes
    return nothing to a co-located radar) and a gap between them no larger than the larger patch."""
    n, c = patches.normal, patches.point
    size = np.sqrt(patches.area)
    out = []
    for a in range(len(n)):
        cos = np.abs(n @ n[a])
        gap = np.linalg.norm(c - c[a], axis=1) - radius - radius[a]
        ok = (cos <= DIHEDRAL_COS + NORMAL_TOL) & (gap <= np.maximum(size, size[a]))
        ok[a] = False
        out.append(np.flatnonzero(ok).tolist())
    return out


def _pair_items(geom, links, colocated, na, pa_pt, mb, xb, side_b, tree_a, members_a, reach_a, vis_lookup,
                tx_ant, rx_ant, cells, areas_m2, k0, polarisation, centre_a, radius_a, aperture):
    """Items of the double bounces off patch A, then one of the surfels mb of its partners, for every
    co-located link; aperture: A's `edges.patch_coverage` (its boundary)."""
    tx = links.tx_m.numpy()
    rx = links.rx_m.numpy()
    side_tx = (tx - pa_pt) @ na                                           # [M]
    ok_link = colocated & (np.abs(side_tx) > 1e-9)
    ml = np.flatnonzero(ok_link)
    if ml.size == 0:
        return None
    tx_img = tx[ml] - 2.0 * side_tx[ml, None] * na[None]                  # [M', 3]
    # every (link, m of B) with m on Tx's side of A whose segment Tx_A -> m crosses plane A near A: a
    # conservative test on the [M', B] grid first (most candidates end here), then the exact one
    li, bi = crossing_candidates(tx[ml] - pa_pt, side_tx[ml], xb - pa_pt, side_b, na, radius_a + reach_a)
    if li.size == 0:
        return None
    # the second leg lit: V(Rx -> m) among the first-order pairs (a lookup, cheaper than the exact
    # crossing below and leaving few candidates to it: first)
    v_b = vis_lookup(torch.as_tensor(ml[li]), torch.as_tensor(mb[bi]))
    lit = (v_b > 0).numpy()
    li, bi, v_b = li[lit], bi[lit], v_b[torch.as_tensor(lit)]
    if li.size == 0:
        return None
    t, c = segment_crossing(tx_img[li], xb[bi], pa_pt, na)               # crossing with plane A
    valid = (t > 0) & (t < 1) & (np.linalg.norm(c - centre_a, axis=1) <= radius_a + reach_a)  # near A at all
    li, bi, c, v_b = li[valid], bi[valid], c[valid], v_b[torch.as_tensor(valid)]
    if li.size == 0:
        return None
    valid, near = aperture_hits(c, tree_a, members_a, reach_a, aperture)   # inside A's boundary: its true edge
    li, bi, c, near, v_b = li[valid], bi[valid], c[valid], near[valid], v_b[torch.as_tensor(valid)]
    if li.size == 0:
        return None
    link = ml[li]
    lt = torch.as_tensor(link)
    # the lit surfel of A nearest the crossing whose cell holds it (a thin plate's far face is close
    # by, and shadowed; past A's edge no cell holds it: a convex edge makes no double bounce)
    v_near = vis_lookup(lt[:, None], torch.as_tensor(members_a[near]))   # [I, k_near]
    on_cell = _in_cell(torch.as_tensor(c)[:, None], geom.means[torch.as_tensor(members_a[near])],
                       cells[torch.as_tensor(members_a[near])])
    v_near = torch.where(on_cell, v_near, torch.zeros_like(v_near))
    v_a, pick = v_near.max(1)
    ga = members_a[near[np.arange(len(near)), pick.numpy()]]
    gb = mb[bi]
    v = v_a * v_b
    keep = (v > 1e-6).numpy()
    if not keep.any():
        return None
    link, ga, gb, c, v = link[keep], ga[keep], gb[keep], c[keep], v[keep]
    src = torch.as_tensor(tx[link] - 2.0 * ((tx[link] - pa_pt) @ na)[:, None] * na[None])
    xm = geom.means[torch.as_tensor(gb)]
    nb = geom.normals[torch.as_tensor(gb)]
    to_src = src - xm
    d_i = to_src.norm(dim=-1)
    w_i = to_src / d_i[:, None]
    to_rx = torch.as_tensor(rx[link]) - xm
    d_o = to_rx.norm(dim=-1)
    w_o = to_rx / d_o[:, None]
    nb = nb * torch.where((w_i * nb).sum(-1, keepdim=True) >= 0, 1.0, -1.0)
    cos_b = (w_i * nb).sum(-1)
    cos_o = (w_o * nb).sum(-1)
    sel = ((cos_b > 1e-6) & (cos_o > 1e-6)).numpy()
    if not sel.any():
        return None
    idx = torch.as_tensor(np.flatnonzero(sel))
    link, ga, gb, c = link[sel], ga[sel], gb[sel], c[sel]
    v, nb, w_i, w_o, d_i, d_o, cos_b, cos_o = (q.index_select(0, idx) for q in (v, nb, w_i, w_o, d_i, d_o, cos_b, cos_o))
    tx_t = torch.as_tensor(tx[link])
    to_c = torch.as_tensor(c) - tx_t
    u_c = to_c / to_c.norm(dim=-1, keepdim=True)                          # Tx -> crossing point
    na_t = torch.as_tensor(na)
    na_t = na_t[None] * torch.where((u_c @ na_t)[:, None] < 0, 1.0, -1.0)  # facing the transmitter
    cos_a = -(u_c * na_t).sum(-1)
    g_t = tx_ant.gain(u_c, links.tx_axis[torch.as_tensor(link)])
    g_r = rx_ant.gain(-w_o, links.rx_axis[torch.as_tensor(link)])
    q = w_i + w_o
    q_cell = torch.einsum("pcj,pj->pc", cells[torch.as_tensor(gb)], q)
    # the obliquity is in the PO factors (second_bounce_factors): m is lit from one direction, seen from another
    amp = torch.sqrt(g_t * g_r) * v * areas_m2[torch.as_tensor(gb)] / (4 * math.pi * d_i * d_o)
    coef = image_coef(amp, q_cell, d_i + d_o, k0)
    return {"link": torch.as_tensor(link), "ga": torch.as_tensor(ga), "gb": torch.as_tensor(gb),
            "cos_a": cos_a, "cos_b": cos_b, "pol": second_bounce_factors(u_c, na_t, -w_i, nb, w_o, polarisation),
            "coef": coef}


def _unit(v: torch.Tensor) -> torch.Tensor:
    return v / v.norm(dim=-1, keepdim=True).clamp(min=1e-300)


def mirror_points(x: np.ndarray, point: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """[..., 3] m: the mirror images of points x [..., 3] m in the planes through point with unit normal
    ([3] or [..., 3] each): the image sources of the bounce terms. The dot product is written out (the order of
    numpy's sum over a last axis of 3, several times faster than that reduction on long arrays)."""
    r = x - point
    side = r[..., 0] * normal[..., 0] + r[..., 1] * normal[..., 1] + r[..., 2] * normal[..., 2]
    return x - 2.0 * side[..., None] * normal


def polarisation_chain(i_a: torch.Tensor, n_a: torch.Tensor, i_b: torch.Tensor, n_b: torch.Tensor,
                       to_rx: torch.Tensor, pol: str) -> torch.Tensor:
    """[I, 4] factors c_XY with p_r . T_B T_A p_t = sum_XY c_XY R_X(A) R_Y(B), XY = (TE, TE), (TE, TM),
    (TM, TE), (TM, TM): `reflection_chain` of two reflections.

    i_a: the wave's direction Tx -> A, n_a: A's normal facing it; i_b: A -> B (the reflected
    direction), n_b: B's normal facing it; to_rx: B -> Rx; all [I, 3] unit. The polarisation is
    carried from one bounce to the next: a scalar co-polarised coefficient per bounce gets the sign of
    the TM-TM path wrong (a dihedral returns E across its fold with the opposite sign to E along it:
    +1 and -1 times a plate's return)."""
    return reflection_chain([i_a, i_b], [n_a, n_b], to_rx, pol)


def reflection_chain(dirs: list, normals: list, to_rx: torch.Tensor, pol: str) -> torch.Tensor:
    """[I, 2^N] factors c_X1..XN with p_r . T_N ... T_1 p_t = sum c_X1..XN R_X1(1) ... R_XN(N) for N
    specular reflections in a row, X in (TE, TM), the first reflection's index slowest (TE before TM).

    dirs: N directions [I, 3] (unit) of the wave arriving at reflection 1..N, each the mirror image of
    the one before; normals: N planes' normals [I, 3], each facing its wave; to_rx [I, 3]: the last
    plane -> Rx. A reflection is T = R_TE e_TE e_TE^T + R_TM e_TM,r e_TM,i^T (`reflection_basis`; a
    perfect conductor has R_TE = -1, R_TM = +1, T = minus the mirror image); p_t, p_r the antennas'
    polarisations (`antenna_polarisation`, the receiver's along -to_rx)."""
    p_t = antenna_polarisation(dirs[0], pol)
    p_r = antenna_polarisation(-to_rx, pol)
    dot = lambda u, v: (u * v).sum(-1)  # noqa: E731
    ends = [((te, te), (tmi, tmr)) for te, tmi, tmr in (reflection_basis(i, n) for i, n in zip(dirs, normals))]
    out = []
    for path in itertools.product(*ends):          # (in, out) of each reflection, the first slowest
        f = dot(p_r, path[-1][1])
        for k in range(len(path) - 1, 0, -1):
            f = f * dot(path[k][0], path[k - 1][1])
        out.append(f * dot(path[0][0], p_t))
    return torch.stack(out, -1)


def _po_radiation(n: torch.Tensor, s: torch.Tensor, p: torch.Tensor, e: torch.Tensor, h: torch.Tensor) -> torch.Tensor:
    """[I]: p . [s x (s x (n x h) - n x e)] = -p . (n x h) - (n x e) . (p x s), the far field toward s
    (unit) of the PO currents J = n x H, M = -n x E of the surface fields e, h = eta H [I, 3] on a plane of
    normal n, projected on the receive polarisation p (p . s = 0); the PO solver's factor
    (rfir_stages.po.solver), which is twice the model's amplitude: a perfect conductor at specular
    reflection, E normal to the plane of incidence, gives -2 cos_i against Gamma cos_i with Gamma = -1."""
    cross = lambda u, v: torch.linalg.cross(u, v, dim=-1)  # noqa: E731
    return -(p * cross(n, h)).sum(-1) - (cross(n, e) * cross(p, s)).sum(-1)


def second_bounce_factors(i_a: torch.Tensor, n_a: torch.Tensor, i_b: torch.Tensor, n_b: torch.Tensor,
                          to_rx: torch.Tensor, pol: str) -> torch.Tensor:
    """[I, 6] factors (b_TT, b_TM, b_MT, b_MM, b_T0, b_M0) with the second bounce's physical optics
    sum_X R_X(A) (sum_Y b_XY R_Y(B) + b_X0), X, Y in (TE, TM): P_m of the module docstring, the
    obliquity included; arguments as `polarisation_chain` (to_rx: B -> Rx, the scattering direction).
    `bounce_factors` of one specular reflection before the physical optics of B."""
    return bounce_factors([i_a, i_b], [n_a, n_b], to_rx, pol)


def bounce_factors(dirs: list, normals: list, to_rx: torch.Tensor, pol: str) -> torch.Tensor:
    """[I, 2^N + 2^(N-1)] physical-optics factors of N - 1 specular reflections followed by the physical
    optics of the last plane: first b_X1..XN (the 2^N products R_X1 ... R_XN, the first reflection's
    index slowest), then b_X1..X(N-1),0 (the 2^(N-1) products without the last plane's coefficient), with
    the field sum_X1..X(N-1) R_X1 ... R_X(N-1) (sum_XN b_X1..XN R_XN + b_X1..X(N-1),0); arguments as
    `reflection_chain` (to_rx: the last plane -> Rx, the scattering direction; it need not be the mirror
    image of the last wave).

    The N - 1 reflections are geometric optics (`reflection_basis`): each part X1..X(N-1) of p_t reaches
    the last plane as the field e = e_X(N-1),r (e_X(N-1),i . ... e_X1,r (e_X1,i . p_t)). On that plane e
    and its reflection R_TE (e . e_TE) e_TE + R_TM (e . e_TM,i) e_TM,r carry the PO currents, radiated
    toward Rx and projected on p_r (`_po_radiation`, halved to the model's normalisation). Where the last
    plane reflects specularly toward Rx (to_rx the mirror of its wave) b_X1..XN = c_X1..XN cos_i'
    (`reflection_chain`) and b_..0 = 0, which is why a corner reflector's flash needs no more than the
    chain; off that direction the incident field's own currents (b_..0) and the different obliquities of
    the TE and TM currents count: in the last plane of incidence the TE factor is
    R_TE (cos_i' + cos_o) / 2 + (cos_o - cos_i') / 2."""
    p_t = antenna_polarisation(dirs[0], pol)
    p_r = antenna_polarisation(-to_rx, pol)
    i_l, n_l = dirs[-1], normals[-1]
    te_l, tmi_l, tmr_l = reflection_basis(i_l, n_l)
    r_l = i_l - 2.0 * (i_l * n_l).sum(-1, keepdim=True) * n_l
    cross = lambda u, v: torch.linalg.cross(u, v, dim=-1)  # noqa: E731
    dot = lambda u, v: (u * v).sum(-1)  # noqa: E731
    rad_te = 0.5 * _po_radiation(n_l, to_rx, p_r, te_l, cross(r_l, te_l))      # the last plane's TE reflection, per unit
    rad_tm = 0.5 * _po_radiation(n_l, to_rx, p_r, tmr_l, cross(r_l, tmr_l))    # its TM reflection, per unit
    fields = [p_t]
    for te, tmi, tmr in (reflection_basis(i, n) for i, n in zip(dirs[:-1], normals[:-1])):
        fields = [out * dot(inn, e)[:, None] for e in fields for inn, out in ((te, te), (tmi, tmr))]
    out_xy, out_x0 = [], []
    for e in fields:                                                             # each path's field at the last plane
        out_xy += [dot(e, te_l) * rad_te, dot(e, tmi_l) * rad_tm]
        out_x0.append(0.5 * _po_radiation(n_l, to_rx, p_r, e, cross(i_l, e)))
    return torch.stack(out_xy + out_x0, -1)


def image_coef(amp: torch.Tensor, q_cell: torch.Tensor, path_m: torch.Tensor, k0: torch.Tensor) -> torch.Tensor:
    """[I, K] complex j amp F_m(k) exp(-j k path): a bounce item's coefficient without its polarisation
    factors and reflection coefficients; amp [I] (sqrt(G_T G_R) V A_m / (4 pi d_i' d_o), 1/m^0), q_cell [I, 2]
    m (the surfel's cell times w_i + w_o, surfels.footprint_factor), path_m [I] the unfolded length
    d_i' + d_o, k0 [K] rad/m."""
    return (1j * amp)[:, None] * footprint_factor(q_cell, k0) * torch.exp(-1j * path_m[:, None] * k0[None])


def segment_crossing(src: np.ndarray, dst: np.ndarray, point: np.ndarray, normal: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(t [N], c [N, 3] m): where the segments src -> dst [N, 3] m cross the plane through `point` with
    `normal` ([3] each, or one plane per segment [N, 3]) (c = src + t (dst - src); the segment crosses it
    for 0 < t < 1; NaN when parallel)."""
    d = dst - src
    dot = (lambda u, v: u @ v) if np.ndim(normal) == 1 else (lambda u, v: (u * v).sum(1))  # noqa: E731
    denom = dot(d, normal)
    t = dot(point - src, normal) / np.where(np.abs(denom) > 1e-12, denom, np.nan)
    return t, src + t[:, None] * d


def aperture_hits(c: np.ndarray, tree, members: np.ndarray, reach: float, aperture) -> tuple[np.ndarray, np.ndarray]:
    """(valid [N] bool, near [N, k] positions in `members`, nearest first): crossings c [N, 3] m on a patch's
    plane inside its aperture (the patch's boundary, `edges.patch_coverage`: its true edge) and within
    `reach` of its nearest member; tree: a cKDTree of the members' means. The k <= 4 nearest members are
    the candidates for the cell that holds the crossing (`_in_cell`)."""
    k_near = min(4, len(members))
    dist, near = tree.query(c, k=k_near)
    dist, near = dist.reshape(len(c), k_near), near.reshape(len(c), k_near)
    return (dist[:, 0] < reach) & aperture.inside(c), near


def _in_cell(point: torch.Tensor, centre: torch.Tensor, cell: torch.Tensor) -> torch.Tensor:
    """[...] bool: `point` [..., 3] lies on the rectangle cell (surfels.footprint_cells) of the surfel
    at `centre` [..., 3] with half-side axes `cell` [..., 2, 3], within CELL_MARGIN of its half-sides
    (projected on its plane)."""
    rel = point - centre
    half2 = (cell * cell).sum(-1).clamp(min=1e-300)                      # [..., 2] squared half-sides
    coord = torch.einsum("...j,...cj->...c", rel, cell) / half2           # in units of half-sides
    return (coord.abs() <= 1.0 + CELL_MARGIN).all(-1)


def crossing_candidates(tx_rel: np.ndarray, side_tx: np.ndarray, xb_rel: np.ndarray, side_b: np.ndarray,
                        na: np.ndarray, reach: float, block: int = 1 << 22) -> tuple[np.ndarray, np.ndarray]:
    """(li, bi): the (link, m) index pairs, in row-major order, with Tx and m on the same side of plane A
    (side_tx, side_b of one sign) that pass `_crossing_near`'s test; arguments as there.

    The same test as `np.nonzero(same_side & _crossing_near(...))`, computed as one [M', B] product:
    with the in-plane parts q, r and offsets s, b, |b q + s r|^2 - R^2 (s + b)^2 = F_i . G_j for
        F = (|q|^2 - R^2, 2 s q, -2 R^2 s, s^2),  G = (b^2, b r, b, |r|^2 - R^2),
    evaluated only between the links and surfels on one side of A and the other (the grid of the
    co-located radar's every link against every surfel of the partner patches is the bulk of the
    double bounces' cost). The expansion rounds differently from `_crossing_near`'s; both are
    conservative by the reach's widening (1e-6 of it, orders of magnitude above the rounding), and
    the exact crossing test follows, so the items are the same (tests/model)."""
    q = tx_rel - side_tx[:, None] * na[None]
    r = xb_rel - side_b[:, None] * na[None]
    r2 = (reach * (1.0 + 1e-6) + 1e-12) ** 2
    f = np.concatenate([((q * q).sum(1) - r2)[:, None], 2.0 * side_tx[:, None] * q, (-2.0 * r2 * side_tx)[:, None],
                        (side_tx * side_tx)[:, None]], 1)                                  # [M', 6]
    g = np.concatenate([(side_b * side_b)[:, None], side_b[:, None] * r, side_b[:, None],
                        ((r * r).sum(1) - r2)[:, None]], 1)                                # [B, 6]
    ft, gt = torch.from_numpy(f), torch.from_numpy(g)
    keys = []
    for sign in (1.0, -1.0):
        rows = np.flatnonzero(np.sign(side_tx) == sign)
        cols = np.flatnonzero(np.sign(side_b) == sign)
        if rows.size == 0 or cols.size == 0:
            continue
        gs = gt[torch.from_numpy(cols)].T.contiguous()                                    # [6, B_side]
        step = max(1, block // cols.size)          # bounded memory: [step, B_side] per product
        for a in range(0, rows.size, step):
            rr = rows[a:a + step]
            i, j = torch.nonzero(ft[torch.from_numpy(rr)] @ gs <= 0.0, as_tuple=True)
            keys.append(rr[i.numpy()] * len(side_b) + cols[j.numpy()])
    key = np.sort(np.concatenate(keys)) if keys else np.zeros(0, dtype=np.int64)
    return key // len(side_b), key % len(side_b)


def _crossing_near(tx_rel: np.ndarray, side_tx: np.ndarray, xb_rel: np.ndarray, side_b: np.ndarray, na: np.ndarray,
                   reach: float) -> np.ndarray:
    """[M', B] bool, true wherever the segment from Tx's image in plane A to m can cross the plane
    within `reach` of A's centre (a superset of the exact test: the reach is widened by 1e-6 of itself).

    tx_rel [M', 3], xb_rel [B, 3]: positions relative to A's centre; side_tx [M'], side_b [B]: their
    offsets along A's normal na (Tx and m on the same side). With in-plane parts q, r and offsets s, b,
    the crossing is (b q + s r) / (s + b) from the centre, so the test is |b q + s r|^2 <= R^2 (s + b)^2,
    expanded into outer products and one [M', B] matrix product (no [M', B, 3] arrays)."""
    q = tx_rel - side_tx[:, None] * na[None]
    r = xb_rel - side_b[:, None] * na[None]
    r2 = (reach * (1.0 + 1e-6) + 1e-12) ** 2
    lhs = np.multiply.outer((q * q).sum(1), side_b * side_b)
    lhs += (2.0 * side_tx)[:, None] * (q @ r.T) * side_b[None]
    lhs += np.multiply.outer(side_tx * side_tx, (r * r).sum(1))
    s_plus_b = side_tx[:, None] + side_b[None]
    return lhs <= r2 * s_plus_b * s_plus_b
