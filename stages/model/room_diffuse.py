"""Diffuse scattering in rooms, summed in power over cells of surfels (docs/physics.md sections 8.8 and 8.10).

The Lambertian term of section 8.8 for every link and every lit cell:

    P_diff = sum_c G_T G_R S_m^2 |Gamma_m(theta_c)|^2 A_c cos(theta_i) cos(theta_o) lambda^2 V_c / (16 pi^3 d_i^2 d_o^2)

Diffuse power varies slowly over a surface, so the surfels of each patch are grouped into cells of
about `cell_m` (a voxel grid on the patch): each cell has the summed area, the area-weighted centre
and the patch's normal. Its visibility V_c is that of the specular legs (room_paths): each surface
crossed on the leg from either antenna to the cell's surfel nearest that centre (its anchor) applies
its power transmission |T|^2 at the crossing angle, so a metal wall passes no diffuse power and a
glass one most of it. |Gamma|^2 and |T|^2 are the means of the TE and TM values (the diffuse part
has no definite polarisation).

Everything but the materials and the wavelength is summed once: cells that both antennas see with nothing in
between into per-(link, material, angle node) weights (a fit step costs M x materials x nodes), the others
into weights per (link, material and angle node of the cell, surfaces crossed with their angles)
(ObstructedCells), the crossing angles taken at the nearest of CROSSING_NODES. The weights leave lambda^2
out (m^-2): the frequency enters at evaluation (DiffuseTerms.freq_hz; at_frequency gives the same terms at
another), with the materials' coefficients.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from .link_rows import renumber_links
from rfir_core.physics.materials import C0, abs2, fresnel, slab_transmission
from rfir_core.physics.angle_nodes import AngleNodes
from rfir_core.physics.crossings import leg_crossings
from .room_paths import PatchSet, _dot

NODES = 46   # incidence-angle nodes 0, 2, ..., 90 degrees of a cell's |Gamma|^2, linear between them
# incidence-angle nodes 0, 1, ..., 90 degrees of a crossing's |T|^2, the nearest taken: the terms of one link
# through the same surfaces at the same angles then share one product of |T|^2 (a fit step's cost)
CROSSING_NODES = 91
# surfaces a leg to a cell may cross (each costs at least a wall's transmission): a leg crossing more
# carries no diffuse power
MAX_LEG_CROSSINGS = 3
# patches smaller than this share of a cell's area (cell_m^2) pool their cells by material, facing and voxel
# (RoomSettings takes its default from here)
SMALL_PATCH_SHARE = 0.25
# entries of a point's crossing row [C, MAX_LEG_CROSSINGS]: a patch index, or one of these
NO_CROSSING, UNTRACED, BLOCKED = -1, -2, -3


@dataclass
class DiffuseCells:
    """centre [C, 3], normal [C, 3], area [C] m^2, material [C] int64, patch [C] int64, anchor [C] the surfel
    the legs end on, anchor_m [C, 3] its position."""

    centre: np.ndarray
    normal: np.ndarray
    area: np.ndarray
    material: np.ndarray
    patch: np.ndarray
    anchor: np.ndarray
    anchor_m: np.ndarray


def diffuse_cells(means: np.ndarray, areas_m2: np.ndarray, patches: PatchSet, material_of_patch: np.ndarray,
                  cell_m: float, small_patch_share: float = SMALL_PATCH_SHARE) -> DiffuseCells:
    """Group each patch's surfels into cells of about cell_m (a voxel grid). Patches smaller than
    small_patch_share of a cell (cell_m^2; 0: none) share cells with the other small patches of their material that face
    the same way (the dominant axis of the normal and its sign) in the voxel: diffuse power is summed over a
    cell's area whichever small patches carry it, and Gaussians off every plane (from photos: thousands of
    one-Gaussian patches) would otherwise each be a cell of their own. Such a cell's normal is the area-weighted
    mean of its patches'; its patch (the one its legs start on) is its anchor's."""
    p = patches.surfel_patch
    vox = np.floor(means / cell_m).astype(np.int64)
    n = patches.normal
    axis = np.abs(n).argmax(1)
    facing = 2 * axis + (n[np.arange(len(n)), axis] < 0)
    small = patches.area < small_patch_share * cell_m ** 2
    owner = np.where(small, -1 - (material_of_patch * 6 + facing), np.arange(patches.num))[p]
    key = np.concatenate([owner[:, None], vox], 1)
    _, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    c = int(inv.max()) + 1 if len(inv) else 0
    area = np.bincount(inv, weights=areas_m2, minlength=c)
    centre = np.stack([np.bincount(inv, weights=areas_m2 * means[:, i], minlength=c) for i in range(3)], 1)
    centre /= np.maximum(area, 1e-30)[:, None]
    dist = np.linalg.norm(means - centre[inv], axis=1)
    order = np.lexsort((dist, inv))
    first = order[np.unique(inv[order], return_index=True)[1]]
    patch = p[first]
    # sign-aligned with the anchor's patch (one facing per cell: the signs agree but for rounding at 45 degrees)
    sign = np.where(_dot(n[p], n[patch[inv]]) < 0, -1.0, 1.0)
    normal = np.stack([np.bincount(inv, weights=areas_m2 * sign * n[p, i], minlength=c) for i in range(3)], 1)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    return DiffuseCells(centre, normal, area, material_of_patch[patch], patch, first, means[first])


@dataclass
class ObstructedCells:
    """The diffuse terms whose legs cross surfaces, summed per (link, the cell's material and angle node,
    the surfaces crossed).

    link [K] int64; weight [K] m^-2 the summed Lambertian factors without materials and lambda^2 (each cell's
    share of its two angle nodes); refl [K] int64 flat index material * NODES + node of the cells' |Gamma|^2 S^2;
    combo [K] int64 row of crossings [U, W] int64: flat indices material * CROSSING_NODES + node of each
    crossing's |T|^2, the extra material row num_materials (|T|^2 = 1) in unused slots."""

    link: torch.Tensor
    weight: torch.Tensor
    refl: torch.Tensor
    combo: torch.Tensor
    crossings: torch.Tensor

    def select_links(self, rows, num_links: int) -> "ObstructedCells":
        """The terms of links `rows` (renumbered 0..len(rows)-1 in that order)."""
        _, keep, new_link = renumber_links(self.link, num_links, rows)
        return ObstructedCells(new_link, self.weight[keep], self.refl[keep], self.combo[keep], self.crossings)


@dataclass
class DiffuseTerms:
    """weight [M, N, NODES] m^-2: sum over the unobstructed cells of material n of the geometric factor without
    lambda^2, spread on the nodes; obstructed: the other cells' terms; freq_hz [M] Hz: the frequency each link is
    evaluated at (at_frequency: the same terms at another)."""

    weight: torch.Tensor
    freq_hz: torch.Tensor
    obstructed: ObstructedCells

    @property
    def num_links(self) -> int:
        return int(self.weight.shape[0])

    def lambda2(self) -> torch.Tensor:
        """[M] m^2: each link's wavelength squared, the factor the weights leave out."""
        return (C0 / self.freq_hz) ** 2

    def at_frequency(self, freq_hz) -> "DiffuseTerms":
        """The same terms evaluated at freq_hz (a number [Hz] for every link, or [M] one per link)."""
        f = torch.as_tensor(np.asarray(freq_hz, dtype=np.float64))
        f = f.expand(self.num_links).clone() if f.ndim == 0 else f
        if f.shape != (self.num_links,):
            raise ValueError(f"freq_hz: expected one frequency or {self.num_links}, got shape {tuple(f.shape)}")
        return DiffuseTerms(self.weight, f, self.obstructed)

    def select_links(self, rows) -> "DiffuseTerms":
        r = torch.as_tensor(np.asarray(rows), dtype=torch.int64)
        return DiffuseTerms(self.weight[r], self.freq_hz[r], self.obstructed.select_links(rows, self.num_links))

    def split_material(self, i: int) -> tuple[torch.Tensor, "DiffuseTerms", "DiffuseTerms"]:
        """(depends [M] bool, without, with): the terms that do not involve material i and those that do (its
        cells' reflectance, or a leg through one of its slabs); power is the sum of the two parts' powers, and
        the links where `depends` is false have no term of the second."""
        ob = self.obstructed
        own = torch.zeros(self.weight.shape[1], dtype=torch.bool)
        own[i] = True
        involved = (ob.refl // NODES == i) | (ob.crossings[ob.combo] // CROSSING_NODES == i).any(1)   # [K]
        depends = (self.weight[:, i] != 0).any(1)
        depends[ob.link[involved]] = True

        def part(keep_column: torch.Tensor, keep_term: torch.Tensor) -> DiffuseTerms:
            return DiffuseTerms(self.weight * keep_column[None, :, None], self.freq_hz, ObstructedCells(
                ob.link[keep_term], ob.weight[keep_term], ob.refl[keep_term], ob.combo[keep_term], ob.crossings))
        return depends, part(~own, ~involved), part(own, involved)

    def material_form(self, i: int, eta_of_material: torch.Tensor, thickness_m: torch.Tensor | None,
                      scattering: torch.Tensor) -> "MaterialDiffuse":
        """The power of these terms as a function of material i alone, the others held at eta [N, 1] (one
        frequency), thickness [N] m (None: half-spaces), S [N]: each term is a fixed factor times material i's
        |Gamma|^2 S^2 at its node (where the cell is of material i) and |T|^2 at each crossing of its slabs."""
        if eta_of_material.shape[1] != 1:
            raise ValueError("material_form takes the materials at one frequency")
        g2 = diffuse_reflectance(eta_of_material, thickness_m, scattering, self.freq_hz).reshape(-1)
        t2 = diffuse_transmittance(eta_of_material, thickness_m, self.freq_hz)
        t2 = torch.cat([t2, torch.ones_like(t2[:1])]).reshape(-1)          # the row of "no crossing"
        ob = self.obstructed
        lam2 = self.lambda2()
        x = ob.crossings                                                     # [U, W] flat crossing indices
        mine_r, mine_x = ob.refl // NODES == i, x // CROSSING_NODES == i
        # material i's factors look up [its NODES values, 1] and [its CROSSING_NODES values, 1]; the crossings
        # per combination of surfaces and angles, as power() does (terms share them)
        r_at = torch.where(mine_r, ob.refl % NODES, NODES)
        x_at = torch.where(mine_x, x % CROSSING_NODES, CROSSING_NODES)
        others = torch.where(mine_x, 1.0, t2[x]).prod(1)
        fixed = ob.weight * lam2[ob.link] * torch.where(mine_r, 1.0, g2[ob.refl]) * others[ob.combo]
        weight = self.weight[:, i] * lam2[:, None]
        if len(ob.link) == 0:
            return MaterialDiffuse(i, weight, self.freq_hz, ob.link, fixed, r_at, x_at, ob.combo)
        # terms alike in material i (the same link, node and crossings of it) are one term of summed factors
        x_at, row = torch.unique(x_at, dim=0, return_inverse=True)
        key = (ob.link * (NODES + 1) + r_at) * len(x_at) + row[ob.combo]
        key, term = torch.unique(key, return_inverse=True)
        fixed = torch.zeros(len(key), dtype=torch.float64).index_add(0, term, fixed)
        combo, r_at = key % len(x_at), key // len(x_at) % (NODES + 1)
        link = key // len(x_at) // (NODES + 1)
        return MaterialDiffuse(i, weight, self.freq_hz, link, fixed, r_at, x_at, combo)

    def power(self, eta_of_material: torch.Tensor, thickness_m: torch.Tensor | None,
              scattering: torch.Tensor) -> torch.Tensor:
        """P_diff [M] W (P_T = 1 W) for materials' eta [N, 1] (one frequency) or [N, M], thickness [N], S [N]."""
        g2 = diffuse_reflectance(eta_of_material, thickness_m, scattering, self.freq_hz)
        one_freq = eta_of_material.shape[1] == 1
        lam2 = self.lambda2()
        p = (self.weight * g2[None]).sum((1, 2)) if one_freq else (self.weight * g2.permute(1, 0, 2)).sum((1, 2))
        p = p * lam2
        ob = self.obstructed
        if len(ob.link) == 0:
            return p
        t2 = diffuse_transmittance(eta_of_material, thickness_m, self.freq_hz)
        t2 = torch.cat([t2, torch.ones_like(t2[:1])])                     # the row of "no crossing"
        if one_freq:
            through = t2.reshape(-1)[ob.crossings].prod(1)[ob.combo]      # each combination's product once
            term = ob.weight * g2.reshape(-1)[ob.refl] * through
        else:   # [N, M, nodes]: each term at its link's frequency
            m = self.num_links
            r_at = ((ob.refl // NODES) * m + ob.link) * NODES + ob.refl % NODES
            x = ob.crossings[ob.combo]
            t_at = ((x // CROSSING_NODES) * m + ob.link[:, None]) * CROSSING_NODES + x % CROSSING_NODES
            term = ob.weight * g2.reshape(-1)[r_at] * t2.reshape(-1)[t_at].prod(1)
        return p.index_add(0, ob.link, term * lam2[ob.link])


@dataclass
class MaterialDiffuse:
    """Diffuse terms as a function of one material (DiffuseTerms.material_form), at the frequency it was formed at:
    weight [M, NODES] of its unobstructed cells (lambda^2 included); per obstructed term k: link [K], fixed [K] (the
    factors of the other materials and lambda^2), r_at
    [K] its node of material i's |Gamma|^2 S^2 (NODES: none), combo [K] its row of x_at [U, W]: the crossings'
    nodes of material i's |T|^2 (CROSSING_NODES: none)."""

    material: int
    weight: torch.Tensor
    freq_hz: torch.Tensor
    link: torch.Tensor
    fixed: torch.Tensor
    r_at: torch.Tensor
    x_at: torch.Tensor
    combo: torch.Tensor

    def power(self, g2: torch.Tensor, t2: torch.Tensor) -> torch.Tensor:
        """P_diff [M] W (P_T = 1 W) of these terms for the material's |Gamma|^2 S^2 g2 [NODES] and |T|^2 t2
        [CROSSING_NODES] (diffuse_reflectance, diffuse_transmittance)."""
        one = torch.ones(1, dtype=torch.float64)
        p = self.weight @ g2
        if len(self.link) == 0:
            return p
        term = self.fixed * torch.cat([g2, one])[self.r_at] * torch.cat([t2, one])[self.x_at].prod(1)[self.combo]
        return p.index_add(0, self.link, term)


def _angle_nodes(num: int = NODES) -> torch.Tensor:
    """cos of num incidence angles evenly spaced over 0..90 degrees."""
    return AngleNodes(num).cosines()


def diffuse_reflectance(eta_of_material: torch.Tensor, thickness_m: torch.Tensor | None, scattering: torch.Tensor,
                        freq_hz: torch.Tensor) -> torch.Tensor:
    """|Gamma|^2 S^2 on the NODES incidence angles: [N, NODES] for eta [N, 1] (one frequency, freq_hz[0]) or
    [N, M, NODES] for eta [N, M] at the links' freq_hz [M]; |Gamma|^2 = (|R_TE|^2 + |R_TM|^2) / 2, S [N],
    thickness [N] m (None: half-spaces)."""
    cos = _angle_nodes()
    if eta_of_material.shape[1] == 1:
        k0 = 2 * math.pi * freq_hz[:1] / C0
        th = None if thickness_m is None else thickness_m[:, None]
        r_te, r_tm = fresnel(eta_of_material, cos[None], k0[None], th)                    # [N, NODES]
        return 0.5 * (abs2(r_te) + abs2(r_tm)) * (scattering ** 2)[:, None]
    k0 = 2 * math.pi * freq_hz / C0                                                          # [M]
    th = None if thickness_m is None else thickness_m[:, None, None]
    r_te, r_tm = fresnel(eta_of_material[:, :, None], cos[None, None], k0[None, :, None], th)  # [N, M, NODES]
    return 0.5 * (abs2(r_te) + abs2(r_tm)) * (scattering ** 2)[:, None, None]


def diffuse_transmittance(eta_of_material: torch.Tensor, thickness_m: torch.Tensor | None,
                          freq_hz: torch.Tensor) -> torch.Tensor:
    """|T|^2 = (|T_TE|^2 + |T_TM|^2) / 2 of each material's slab on the CROSSING_NODES incidence angles:
    [N, CROSSING_NODES] for eta [N, 1], [N, M, CROSSING_NODES] for eta [N, M]; 0 for half-spaces (thickness
    None)."""
    cos = _angle_nodes(CROSSING_NODES)
    if eta_of_material.shape[1] == 1:
        eta, cos, k0 = eta_of_material, cos[None], (2 * math.pi * freq_hz[:1] / C0)[None]
        th = None if thickness_m is None else thickness_m[:, None]
    else:
        eta, cos, k0 = eta_of_material[:, :, None], cos[None, None], (2 * math.pi * freq_hz / C0)[None, :, None]
        th = None if thickness_m is None else thickness_m[:, None, None]
    if th is None:
        return torch.zeros(torch.broadcast_shapes(eta.shape, cos.shape), dtype=torch.float64)
    t_te, t_tm = slab_transmission(eta, cos, k0, th)
    return 0.5 * (abs2(t_te) + abs2(t_tm))


class CellCrossings:
    """The surfaces crossed on the legs from points to every diffuse cell (to its anchor surfel), kept per point.

    A point's row [C, MAX_LEG_CROSSINGS] int32 holds the patches each leg crosses (NO_CROSSING in unused
    slots; BLOCKED: more than MAX_LEG_CROSSINGS; UNTRACED: not traced yet). It depends on the point and the
    geometry only, not on the materials or the other end of a link: a radio map's receivers are traced once
    per model and every later transmitter reuses them. Only the entries a call needs are traced (a cell with
    the link's ends on opposite sides of its plane scatters nothing between them); the others are traced
    when a later call needs them. Rows are kept up to max_bytes, the oldest dropped first; points are keyed
    rounded to 1 nm. The crossings are found as for the specular legs (rfir_core.physics.crossings.leg_crossings)."""

    def __init__(self, cells: DiffuseCells, patches: PatchSet, provider, max_bytes: float = 256e6):
        self.cells, self.patches, self.provider = cells, patches, provider
        self.max_rows = max(1, int(max_bytes // max(1, 4 * MAX_LEG_CROSSINGS * len(cells.area))))
        self._rows: dict[bytes, np.ndarray] = {}

    def _trace(self, points: np.ndarray, cells: np.ndarray) -> np.ndarray:
        """Crossing rows [Q, MAX_LEG_CROSSINGS] of the legs points [Q, 3] -> anchors of cells [Q]."""
        q = len(cells)
        leg, patch, _ = leg_crossings(self.provider, self.patches, points, self.cells.anchor_m[cells],
                                      np.full(q, -1), self.cells.patch[cells])
        out = np.full((q, MAX_LEG_CROSSINGS), NO_CROSSING, dtype=np.int32)
        count = np.bincount(leg, minlength=q)
        order = np.argsort(leg, kind="stable")
        leg, patch = leg[order], patch[order]
        slot = np.arange(len(leg)) - np.repeat(np.cumsum(count) - count, count)
        fits = slot < MAX_LEG_CROSSINGS
        out[leg[fits], slot[fits]] = patch[fits]
        out[count > MAX_LEG_CROSSINGS] = NO_CROSSING
        out[count > MAX_LEG_CROSSINGS, 0] = BLOCKED
        return out

    def __call__(self, points: np.ndarray, need: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(rows [U, C, MAX_LEG_CROSSINGS] int32 of the distinct points, index [N] of each point's row).

        need [N, C] bool: the entries each point needs (None: all); entries no point needs and not traced
        before are UNTRACED."""
        c = len(self.cells.area)
        uniq, inv = np.unique(np.round(points, 9), axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        keys = [u.tobytes() for u in uniq]
        out = np.full((len(keys), c, MAX_LEG_CROSSINGS), NO_CROSSING, dtype=np.int32)
        out[:, :, 0] = UNTRACED
        new = []
        for i, k in enumerate(keys):
            row = self._rows.get(k)
            if row is None:
                new.append(i)
            else:
                out[i] = row
        untraced = out[:, :, 0] == UNTRACED
        missing = untraced if need is None else _rows_any(np.asarray(need, dtype=bool), inv, len(keys)) & untraced
        cell, row = np.nonzero(np.ascontiguousarray(missing.T))    # cell after cell, each from every point
        if len(cell):
            out[row, cell] = self._trace(uniq[row], cell)
        old = [i for i in np.flatnonzero(missing.any(1)) if keys[i] in self._rows]    # kept rows traced further
        self._rows.update((keys[i], out[i].copy()) for i in old)
        if new and len(new) <= self.max_rows:
            if len(self._rows) + len(new) > self.max_rows:
                mine = set(keys)
                for k in [k for k in self._rows if k not in mine][:len(self._rows) // 2 + len(new)]:
                    del self._rows[k]
            self._rows.update((keys[i], out[i].copy()) for i in new)
        return out, inv

    def __len__(self) -> int:
        """Points kept."""
        return len(self._rows)

    def clear(self) -> None:
        self._rows.clear()

    def keep(self, points: np.ndarray, rows: np.ndarray) -> None:
        """Keep rows [U, C, MAX_LEG_CROSSINGS] of points [U, 3] traced elsewhere with the same geometry (a model's
        stored map receivers; RoomGeometry.crossings_key says when they apply)."""
        for p, r in zip(np.round(np.asarray(points, np.float64), 9), np.asarray(rows, np.int32)):
            if len(self._rows) < self.max_rows:
                self._rows[p.tobytes()] = r


def _rows_any(need: np.ndarray, inv: np.ndarray, num: int) -> np.ndarray:
    """[num, C] bool: row u is the OR of the rows of need [N, C] with inv [N] == u (every u in 0..num-1 occurs)."""
    if num == len(inv):                                  # distinct points (a map's receivers): a permutation
        out = np.empty_like(need)
        out[inv] = need
        return out
    order = np.argsort(inv, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(inv[order]) != 0])
    return np.logical_or.reduceat(need[order], starts, axis=0)


def _angle_node(cos: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(node int64, frac): the incidence angle of |cos| between angle nodes node and node + 1."""
    return AngleNodes(NODES).position(np.abs(cos))


def _cell_factors(tx: np.ndarray, rx: np.ndarray, cells: DiffuseCells, tx_gain=None, rx_gain=None, tx_axes=None,
                  rx_axes=None):
    """Per (link, cell) of links tx, rx [B, 3] m: (g [B, C] m^-2 the Lambertian factor
    G_T G_R A cos(theta_i) cos(theta_o) / (16 pi^3 d_i^2 d_o^2) of section 8.8 without V and lambda^2 (applied at
    evaluation), 0 where the ends lie on opposite sides of the cell; node [B, C] int64 and frac [B, C]: theta_i
    between angle nodes node and node + 1). tx_gain / rx_gain: callables (unit directions [N, 3] from the antenna
    toward the cells' centres[, their links' antenna axes [N, 3] when tx_axes / rx_axes [B, 3] are given]) -> linear
    power gain [N]; None: isotropic (1)."""
    wi = tx[:, None, :] - cells.centre[None]                        # [B, C, 3]
    wo = rx[:, None, :] - cells.centre[None]
    n = cells.normal[None]
    di2, do2 = _dot(wi, wi), _dot(wo, wo)
    di, do = np.sqrt(di2), np.sqrt(do2)
    ci = _dot(wi, n) / di
    co = _dot(wo, n) / do
    lit = ci * co > 0                                                  # both ends on one side
    ci, co = np.abs(ci), np.abs(co)
    g = (cells.area[None] * ci * co / (16 * math.pi ** 3 * di ** 2 * do ** 2)) * lit
    for gain, w, d, axes in ((tx_gain, wi, di, tx_axes), (rx_gain, wo, do, rx_axes)):
        if gain is not None:   # w points from the cell to the antenna: the antenna sends (or hears) along -w
            per_link = () if axes is None else (np.repeat(np.asarray(axes, np.float64), g.shape[1], axis=0),)
            g = g * np.asarray(gain((-w / np.maximum(d, 1e-300)[..., None]).reshape(-1, 3), *per_link),
                               np.float64).reshape(g.shape)
    node, frac = _angle_node(ci)
    return g, node, frac


def _crossing_slots(points: np.ndarray, rows: np.ndarray, cells: np.ndarray, dc: DiffuseCells, patches: PatchSet,
                    material_of_patch: np.ndarray, num_materials: int) -> np.ndarray:
    """Flat |T|^2 indices material * CROSSING_NODES + nearest node [E, K] of the crossings rows [E, K] on the legs
    points [E, 3] -> anchors of cells [E]; unused slots index the row num_materials (|T|^2 = 1)."""
    d = dc.anchor_m[cells] - points
    d /= np.linalg.norm(d, axis=1, keepdims=True).clip(1e-12)
    used = rows >= 0
    p = np.where(used, rows, 0)
    cos = np.abs(_dot(d[:, None, :], patches.normal[p]))
    node = AngleNodes(CROSSING_NODES).nearest(cos)
    return np.where(used, material_of_patch[p] * CROSSING_NODES + node, num_materials * CROSSING_NODES)


def diffuse_terms(tx_m: np.ndarray, rx_m: np.ndarray, freq_hz: np.ndarray, cells: DiffuseCells,
                  material_of_patch: np.ndarray, num_materials: int, crossings: CellCrossings, link_chunk: int = 256,
                  progress_task=None, tx_gain=None, rx_gain=None, tx_axes=None, rx_axes=None) -> DiffuseTerms:
    """The DiffuseTerms of links tx_m, rx_m [M, 3], evaluated at freq_hz [M] Hz (the terms themselves do not
    depend on it: DiffuseTerms.at_frequency); crossings: a CellCrossings of these cells (its kept rows are reused,
    new ones kept); tx_gain / rx_gain: the antennas' power gains toward each cell (_cell_factors; None: isotropic),
    tx_axes / rx_axes [M, 3]: each link's antenna axis for them (None: the callables' own)."""
    tx = np.asarray(tx_m, dtype=np.float64)
    rx = np.asarray(rx_m, dtype=np.float64)
    m = len(tx)
    patches = crossings.patches
    # each end's crossings are needed only where the cell is lit (both ends on one side of its plane, the loop's
    # test below): here from the ends' heights over the planes, with those within 1 nm of a plane kept (rounding
    # differs from the loop's), so every lit entry is traced
    offset = (cells.centre * cells.normal).sum(1)
    h_tx, h_rx = tx @ cells.normal.T - offset, rx @ cells.normal.T - offset                 # [M, C] m
    need = (h_tx * h_rx > 0) | (np.abs(h_tx) < 1e-9) | (np.abs(h_rx) < 1e-9)
    x_tx, i_tx = crossings(tx, need)
    x_rx, i_rx = crossings(rx, need)
    weight = np.zeros((m, num_materials, NODES))
    size = num_materials * NODES
    links, shares, refls, crosses = [], [], [], []
    for lo in range(0, m, link_chunk):
        hi = min(m, lo + link_chunk)
        g, node, frac = _cell_factors(tx[lo:hi], rx[lo:hi], cells, tx_gain, rx_gain,
                                      *(None if a is None else np.asarray(a)[lo:hi] for a in (tx_axes, rx_axes)))
        first_t, first_r = x_tx[i_tx[lo:hi], :, 0], x_rx[i_rx[lo:hi], :, 0]
        clear = (first_t == NO_CROSSING) & (first_r == NO_CROSSING)
        # BLOCKED (and UNTRACED, never lit) legs carry nothing
        crossed = (first_t >= NO_CROSSING) & (first_r >= NO_CROSSING) & ~clear & (g > 0)
        b = hi - lo
        gc = g * clear
        at = ((np.arange(b)[:, None] * num_materials + cells.material[None]) * NODES + node).ravel()
        # one pass in this order: the lower node's shares, then the upper node's (the sums of two index_add_)
        weight[lo:hi] = np.bincount(np.concatenate([at, at + 1]), np.concatenate([(gc * (1 - frac)).ravel(),
                                    (gc * frac).ravel()]), minlength=b * size).reshape(b, num_materials, NODES)
        bi, ci = np.nonzero(crossed)
        if len(bi):
            li = lo + bi
            cross = np.concatenate([
                _crossing_slots(tx[li], x_tx[i_tx[li], ci], ci, cells, patches, material_of_patch, num_materials),
                _crossing_slots(rx[li], x_rx[i_rx[li], ci], ci, cells, patches, material_of_patch, num_materials)], 1)
            refl = cells.material[ci] * NODES + node[bi, ci]
            gi, fi = g[bi, ci], frac[bi, ci]
            links.append(np.concatenate([li, li]))
            shares.append(np.concatenate([gi * (1 - fi), gi * fi]))
            refls.append(np.concatenate([refl, refl + 1]))
            crosses.append(np.concatenate([cross, cross]))
        if progress_task is not None:
            progress_task.advance(hi - lo)
    obstructed = _obstructed(links, shares, refls, crosses, num_materials)
    return DiffuseTerms(torch.from_numpy(weight), torch.as_tensor(np.asarray(freq_hz, dtype=np.float64)), obstructed)


def _obstructed(links: list, shares: list, refls: list, crosses: list, num_materials: int) -> ObstructedCells:
    """ObstructedCells of terms link [E], share [E] (a cell's share of one angle node), refl [E] and crossings
    [E, 2 K] given in chunks: the slots no term uses dropped, the terms with equal (link, refl, crossings)
    summed."""
    none = num_materials * CROSSING_NODES
    if not links:
        z = torch.zeros(0, dtype=torch.int64)
        return ObstructedCells(z, z.double(), z, z, torch.full((1, 1), none, dtype=torch.int64))
    link, share, refl, cross = (np.concatenate(x) for x in (links, shares, refls, crosses))
    cross = np.sort(cross, axis=1)          # the product does not depend on the order: used slots first
    width = max(1, int((cross != none).sum(1).max()))
    cross = cross[:, :width]
    combos, combo = _distinct_rows(cross, none + 1)
    rs = int(num_materials * NODES)
    key = (link * len(combos) + combo) * rs + refl
    keys, inv = np.unique(key, return_inverse=True)
    weight = np.bincount(inv.reshape(-1), weights=share, minlength=len(keys))
    t = lambda x: torch.from_numpy(np.ascontiguousarray(x))  # noqa: E731
    return ObstructedCells(t(keys // rs // len(combos)), t(weight), t(keys % rs), t(keys // rs % len(combos)),
                           t(combos))


def _distinct_rows(rows: np.ndarray, base: int) -> tuple[np.ndarray, np.ndarray]:
    """(distinct rows [U, W], index [E] of each row's) of rows [E, W] of integers in 0..base-1: three columns
    packed per int64 and one lexsort (np.unique(axis=0) sorts rows as records, many times slower)."""
    keys = []
    for lo in range(0, rows.shape[1], 3):
        k = np.zeros(len(rows), np.int64)
        for c in range(lo, min(lo + 3, rows.shape[1])):
            k = k * base + rows[:, c]
        keys.append(k)
    order = np.lexsort(keys[::-1])
    new = np.r_[True, np.any([np.diff(k[order]) != 0 for k in keys], axis=0)]
    index = np.empty(len(rows), np.int64)
    index[order] = np.cumsum(new) - 1
    return rows[order[new]], index
