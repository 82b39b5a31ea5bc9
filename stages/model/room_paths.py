"""Specular paths in rooms by the image method over planar patches of surfels (docs/physics.md section 8.10).

For each link (Tx, Rx) the paths are: the direct path, first-order reflections off every patch and
second-order reflections between pairs of large patches. A patch is a set of coplanar surfels of one
label (`second_order.planar_patches`); its extent is a 2D occupancy grid rasterised from the surfels'
footprints, so a wall with window openings reflects only where it has surfels. Every leg of every
path is checked for the surfaces it crosses: the Gaussian tracer finds candidate patches on the
leg, and the exact crossing point must lie on the patch. A surface is crossed once, however many
Gaussians tile it, and applies its slab transmission coefficient (materials.slab_transmission).

Everything traced depends on geometry only and is computed once per link set (`trace_room_paths`): path
lengths, antenna gains and polarisation vectors, each interaction's kind, patch, incidence angle and TE/TM
directions; no wavelength. The frequency enters at evaluation: `RoomPaths.freq_hz` is the frequency each
link is evaluated at, and `RoomPaths.at_frequency` gives the same paths at another (a band's channels, or a
prediction at a frequency the model was not fitted at) without tracing again. `RoomPaths.field` then
evaluates the received complex amplitude for any material values, with the polarisation carried as a field
vector through every interaction:

    E <- C_TE (E . s) s + C_TM (E . p_in) p_out

s = unit(k_in x n) (TE direction), p = k x s (the TM reference of materials.py), C the reflection
(R, with p_out = k_out x s) or transmission (T, k unchanged) coefficient of the patch's material
at the local incidence angle. Per path

    a = sqrt(G_T G_R) (e_R . E) lambda / (4 pi L) exp(-j k L) prod_refl sqrt(1 - S^2)

with E starting as the transmitter's polarisation vector e_T, L the unfolded path length, S the
scattering coefficient of each reflecting material (the share of the field scattered diffusely).
Shapes: M links, Q paths, I interaction slots per path (padded), P patches, G surfels.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import torch

from .occlusion import FrozenGeometry

from .link_rows import renumber_links
from rfir_core.physics.crossings import leg_crossings
from rfir_core.physics.materials import C0, abs2, fresnel, slab_transmission, specular_share
from rfir_core.physics.polarisation import antenna_polarisation, mirror_direction, reflection_basis
from .second_order import Patches, mirror_points, planar_patches
from .surfels import footprint_cells

# paths with more interactions than this, reflections and surfaces crossed counted alike (a ray tracer's depth;
# Sionna RT's max_depth counts them so), are dropped. 8 keeps what thin furniture lets through (a floor reflection
# under a desk crosses the top's two faces: five interactions); a shallower depth is cheaper but drops those paths,
# and the fit then bends the materials to make up for them (a metal whiteboard below |Gamma| 1); RoomSettings takes
# its default from here
MAX_INTERACTIONS = 8
# (image row, link) pairs of reflection_paths evaluated at once (memory: about 200 bytes each)
PAIR_CHUNK = 250_000
FOOTPRINT_REACH = 0.75    # "disks": a surfel of area A covers a disk of radius 0.75 sqrt(A) (a square tile's corners)
# "tiles": a surfel covers its rectangle cell (docs/physics.md 8.6: its Gaussian's in-plane axes, sides in the
# ratio of its spreads, its area share), and gaps between tiles narrower than TILE_CLOSING tile sides are
# closed: a patch ends where its tiles end. A disk of the area's size widens a desk top's 3 cm edge band by
# centimetres, and legs that graze it cross it falsely.
TILE_CLOSING = 1.0
# the occupancy grid's cell, in tile sides: a crossing point is placed to half a cell, and a leg that passes
# a chair's back or a desk's edge by millimetres must not cross it, as in a ray tracer's exact geometry
CELL_PER_TILE = 0.1
PATCH_EXTENTS = ("disks", "tiles")
# reflections up to MAX_ORDER; second order off patches of at least HIGHER_ORDER_MIN_AREA_M2 (walls, floor,
# ceiling, desk tops), third and higher orders off those of at least THIRD_ORDER_MIN_AREA_M2 (the surfaces that
# bound a room, whiteboards, windows, doors, large tables); RoomSettings takes its defaults from here
MAX_ORDER = 3
HIGHER_ORDER_MIN_AREA_M2 = 0.3
THIRD_ORDER_MIN_AREA_M2 = 1.0
THIRD_ORDER_SMALL_REFLECTIONS = 1


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise dot products of [..., 3] arrays, summed in the order (a b)_x + (a b)_y + (a b)_z as
    numpy's sum over a last axis of 3 does (several times faster than that reduction on long arrays)."""
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1] + a[..., 2] * b[..., 2]


@dataclass
class PatchSet:
    """Planar patches with their extents.

    normal, point, u, v [P, 3]: plane and in-plane axes; area [P] m^2; label [P] (-1: none);
    surfel_patch [G] patch of each surfel; grid: flattened occupancy of all patches, patch p's cells at
    grid_offset[p] + i * grid_shape[p, 1] + j for cell (i, j) of size cell_m[p] from grid_origin[p]."""

    normal: np.ndarray
    point: np.ndarray
    u: np.ndarray
    v: np.ndarray
    area: np.ndarray
    label: np.ndarray
    surfel_patch: np.ndarray
    grid: np.ndarray
    grid_offset: np.ndarray
    grid_shape: np.ndarray
    grid_origin: np.ndarray
    cell_m: np.ndarray
    merge_tol_m: float = 0.0    # RMS offset of the fitted planes (plane_merge; 0: neighbours were joined)

    @property
    def num(self) -> int:
        return int(len(self.area))

    def contains(self, pid: np.ndarray, pts: np.ndarray) -> np.ndarray:
        """[N] bool: point pts[n] (on patch pid[n]'s plane) lies on that patch."""
        rel = pts - self.point[pid]
        a = _dot(rel, self.u[pid])
        b = _dot(rel, self.v[pid])
        i = np.floor((a - self.grid_origin[pid, 0]) / self.cell_m[pid]).astype(np.int64)
        j = np.floor((b - self.grid_origin[pid, 1]) / self.cell_m[pid]).astype(np.int64)
        inside = (i >= 0) & (j >= 0) & (i < self.grid_shape[pid, 0]) & (j < self.grid_shape[pid, 1])
        idx = self.grid_offset[pid] + np.clip(i, 0, None) * self.grid_shape[pid, 1] + np.clip(j, 0, None)
        out = np.zeros(len(pid), dtype=bool)
        out[inside] = self.grid[idx[inside]]
        return out

    def bounding_spheres(self, pid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(centre [N, 3] m, radius [N] m) of a sphere holding every cell of patches pid [N]: about the centre of
        the patch's occupancy grid, through its corners."""
        half = 0.5 * self.grid_shape[pid] * self.cell_m[pid, None]                   # [N, 2] half sides
        mid = self.grid_origin[pid] + half
        centre = self.point[pid] + mid[:, :1] * self.u[pid] + mid[:, 1:] * self.v[pid]
        return centre, np.hypot(half[:, 0], half[:, 1])


def _labelled_planar_patches(geom: FrozenGeometry, areas_m2: torch.Tensor, labels: torch.Tensor | None,
                             coplanar_m: float, merge_scatter_factor: float) -> Patches:
    """`planar_patches` of each label's surfels on their own, merged (every surfel in one patch); the merge
    tolerance kept is the largest of the labels'.

    planar_patches joins neighbours within a radius set by the median surfel size; objects tiled at
    different spacings (fine furniture, coarse walls) would otherwise share one radius, and the coarse
    walls' surfels, farther apart than the fine median, would fall apart into many small patches."""
    if labels is None:
        return planar_patches(geom, areas_m2, None, min_patch_area_m2=0.0, coplanar_m=coplanar_m,
                              merge_scatter_factor=merge_scatter_factor)
    lab = labels.numpy()
    ids = np.full(geom.num, -1)
    normal, point, area, members = [], [], [], []
    count, tol = 0, 0.0
    for value in np.unique(lab):
        idx = np.flatnonzero(lab == value)
        sub = SimpleNamespace(means=geom.means[idx], normals=geom.normals[idx], num=len(idx))
        part = planar_patches(sub, areas_m2[idx], None, min_patch_area_m2=0.0, coplanar_m=coplanar_m,
                              merge_scatter_factor=merge_scatter_factor)
        tol = max(tol, part.merge_tol_m)
        ids[idx] = np.where(part.id >= 0, part.id + count, -1)
        count += len(part.area)
        normal.append(part.normal)
        point.append(part.point)
        area.append(part.area)
        members += [idx[m] for m in part.members]
    return Patches(ids, np.concatenate(normal), np.concatenate(point), np.concatenate(area), members, merge_tol_m=tol)


def _disk_occupancy(centres: np.ndarray, uv: np.ndarray, reach: np.ndarray, cell: float) -> np.ndarray:
    """[C] bool: grid centres [C, 2] within FOOTPRINT_REACH sqrt(A) (reach [n]) + half a cell of one of their 4
    nearest surfels (uv [n, 2])."""
    from scipy.spatial import cKDTree

    k = min(4, len(uv))
    d, near = cKDTree(uv).query(centres, k=k)
    d, near = d.reshape(len(centres), k), near.reshape(len(centres), k)
    return (d <= reach[near] + 0.5 * cell).any(1)


def _tile_occupancy(centres: np.ndarray, uv: np.ndarray, axes: np.ndarray, half: np.ndarray, shape: np.ndarray,
                    closing_cells: int) -> np.ndarray:
    """[C] bool: grid centres [C, 2] (a grid of `shape`) inside the rectangle (unit axes [n, 2, 2], half-sides
    [n, 2] m) of one of their 8 nearest surfels (uv [n, 2]), then closed with a disk of
    closing_cells cells."""
    from scipy import ndimage
    from scipy.spatial import cKDTree

    k = min(8, len(uv))
    near = cKDTree(uv).query(centres, k=k)[1].reshape(len(centres), k)
    along = np.abs(np.einsum("cki,ckai->cka", centres[:, None, :] - uv[near], axes[near]))   # [C, k, 2] per axis
    occupied = (along <= half[near]).all(2).any(1).reshape(shape[0], shape[1])
    r = closing_cells
    padded = np.pad(occupied, r + 1)                                    # the closing must not eat the border
    # closing with the disk {d : |d|^2 <= r^2}, by distance transforms (exact on the grid, and linear in the cells
    # where a structuring element of a tenth-of-a-tile grid costs its 300-odd cells per cell): dilation is a
    # distance to the occupied cells of at most r, erosion of that a distance to the empty ones above r
    dilated = np.rint(ndimage.distance_transform_edt(~padded) ** 2) <= r * r
    closed = np.rint(ndimage.distance_transform_edt(dilated) ** 2) > r * r
    return closed[r + 1:-r - 1, r + 1:-r - 1].ravel()


EXTENT_GRID_FIELDS = ("grid", "grid_offset", "grid_shape", "grid_origin", "cell_m")


def extent_grids(patches: PatchSet) -> dict[str, np.ndarray]:
    """A PatchSet's occupancy grids as arrays to store (the grid packed 8 cells a byte) for build_patch_set's
    `extents`: rasterising them is most of what building a room's patches costs."""
    out = {f: np.asarray(getattr(patches, f)) for f in EXTENT_GRID_FIELDS[1:]}
    out["grid"] = np.packbits(patches.grid)
    out["grid_cells"] = np.asarray(patches.grid.size, np.int64)
    return out


def build_patch_set(geom: FrozenGeometry, areas_m2: torch.Tensor, labels: torch.Tensor | None,
                    coplanar_m: float, *, extent: str, merge_scatter_factor: float = 0.0,
                    max_cells: int = 40_000, extents: dict[str, np.ndarray] | None = None) -> PatchSet:
    """Every surfel in one patch (singletons included): neighbours joined within coplanar_m, or planes fitted to
    merge_scatter_factor times the Gaussians' scatter where that is wider (plane_merge; 0: never);
    extents rasterised from the surfel footprints (see PATCH_EXTENTS): "disks" (_disk_occupancy) or "tiles",
    the rectangle cells of docs/physics.md 8.6 (surfels.footprint_cells) with gaps closed (_tile_occupancy).
    extents: extent_grids of an earlier build from the same surfels, labels and settings (the caller's to
    know: RoomGeometry.extents_key), taken instead of rasterising; ignored when its patch count differs."""
    if extent not in PATCH_EXTENTS:
        raise ValueError(f"patch extent {extent!r}: expected one of {', '.join(PATCH_EXTENTS)}")
    raw = _labelled_planar_patches(geom, areas_m2, labels, coplanar_m, merge_scatter_factor)
    if extents is not None and len(np.asarray(extents["grid_offset"])) == len(raw.members):
        return _patch_set(raw, labels, {
            **{f: np.asarray(extents[f]) for f in EXTENT_GRID_FIELDS[1:]},
            "grid": np.unpackbits(np.asarray(extents["grid"], np.uint8),
                                  count=int(extents["grid_cells"])).astype(bool)})
    x = geom.means.numpy()
    a = areas_m2.detach().numpy()
    if extent == "tiles":     # every surfel's cell, once: [G, 2, 3] unit axes and half-sides [G, 2] m
        rect = footprint_cells(geom.log_scales, geom.rotations, geom.normals, areas_m2.detach().double()).numpy()
        rect_half = np.linalg.norm(rect, axis=2)
        rect_axes = rect / rect_half.clip(1e-300)[:, :, None]
    grids, offsets, shapes, origins, cells = [], [], [], [], []
    offset = 0
    for p, idx in enumerate(raw.members):
        u, v = _patch_axes(raw.normal[p])
        rel = x[idx] - raw.point[p]
        uv = np.stack([rel @ u, rel @ v], 1)
        tile_m = float(np.median(np.sqrt(a[idx])))
        if extent == "tiles":
            half = rect_half[idx]
            reach = np.sqrt((half ** 2).sum(1))
        else:
            reach = FOOTPRINT_REACH * np.sqrt(a[idx])
        lo = uv.min(0) - reach.max()
        hi = uv.max(0) + reach.max()
        cell = max(CELL_PER_TILE * tile_m, 1e-4)
        cell = max(cell, math.sqrt(float(np.prod(hi - lo)) / max_cells))
        shape = np.maximum(np.ceil((hi - lo) / cell).astype(np.int64), 1)
        ci, cj = np.meshgrid(np.arange(shape[0]), np.arange(shape[1]), indexing="ij")
        centres = lo + (np.stack([ci.ravel(), cj.ravel()], 1) + 0.5) * cell
        if extent == "tiles":
            axes = np.stack([rect_axes[idx] @ u, rect_axes[idx] @ v], 2)               # [n, 2, 2] in (u, v)
            occupied = _tile_occupancy(centres, uv, axes, half, shape,
                                       max(int(round(TILE_CLOSING * tile_m / cell)), 1))
        else:
            occupied = _disk_occupancy(centres, uv, reach, cell)
        grids.append(occupied)
        offsets.append(offset)
        shapes.append(shape)
        origins.append(lo)
        cells.append(cell)
        offset += occupied.size
    return _patch_set(raw, labels, {"grid": np.concatenate(grids) if grids else np.zeros(0, bool),
                                    "grid_offset": np.asarray(offsets), "grid_shape": np.asarray(shapes),
                                    "grid_origin": np.asarray(origins), "cell_m": np.asarray(cells)})


def _patch_set(raw: Patches, labels: torch.Tensor | None, grids: dict) -> PatchSet:
    """The PatchSet of patches `raw` with their occupancy grids (extent_grids' fields, the grid unpacked), each
    patch's in-plane axes (_patch_axes, as its grid was rasterised in) and label (_patch_label)."""
    lab = None if labels is None else labels.numpy()
    frames = [_patch_axes(raw.normal[p]) for p in range(len(raw.members))]
    label = [_patch_label(lab, idx) for idx in raw.members]
    return PatchSet(raw.normal.reshape(-1, 3), raw.point.reshape(-1, 3),
                    np.asarray([u for u, _ in frames]).reshape(-1, 3), np.asarray([v for _, v in frames]).reshape(-1, 3),
                    raw.area, np.asarray(label, dtype=np.int64), raw.id, grids["grid"],
                    grids["grid_offset"].astype(np.int64), grids["grid_shape"].astype(np.int64).reshape(-1, 2),
                    np.asarray(grids["grid_origin"], np.float64).reshape(-1, 2),
                    np.asarray(grids["cell_m"], np.float64), raw.merge_tol_m)


def _patch_label(lab: np.ndarray | None, idx: np.ndarray) -> int:
    """A patch's label: the most common of its surfels idx (labels lab [G]; -1 without labels)."""
    return -1 if lab is None else int(np.bincount(lab[idx] - lab[idx].min()).argmax() + lab[idx].min())


def _patch_axes(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """In-plane unit axes (u, v) of a patch of unit normal n [3]: u horizontal unless n is near vertical."""
    u = np.cross(n, [0.0, 0.0, 1.0] if abs(n[2]) < 0.9 else [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


@dataclass
class RoomPaths:
    """Geometry of every specular path; Q paths, I interaction slots.

    link [Q] int64; length_m [Q]; gain [Q] sqrt(G_T G_R); order [Q] (0 direct, 1, 2 reflections);
    e_tx, e_rx [Q, 3] polarisation vectors at departure and arrival; kind [Q, I] (0 none,
    1 reflection, 2 transmission); patch [Q, I]; cos [Q, I] |cos| of the local incidence angle;
    s, p_in, p_out [Q, I, 3] the interaction's TE and TM reference directions: all of it frequency-free.
    freq_hz [M] Hz: the frequency each link is evaluated at (at_frequency: the same paths at another)."""

    num_links: int
    link: torch.Tensor
    length_m: torch.Tensor
    gain: torch.Tensor
    order: torch.Tensor
    e_tx: torch.Tensor
    e_rx: torch.Tensor
    kind: torch.Tensor
    patch: torch.Tensor
    cos: torch.Tensor
    s: torch.Tensor
    p_in: torch.Tensor
    p_out: torch.Tensor
    freq_hz: torch.Tensor

    @property
    def num(self) -> int:
        return int(self.link.numel())

    def slot_use(self) -> list[int]:
        """Number of paths using each interaction slot; paths are stored most interactions first, so
        slot i is used by the first slot_use()[i] paths (cached)."""
        if "_slot_use" not in self.__dict__:
            counts = (self.kind > 0).sum(1)
            if counts.numel() > 1 and bool((counts[1:] > counts[:-1]).any()):
                raise ValueError("room paths must be stored most interactions first")
            self.__dict__["_slot_use"] = [int(u) for u in (self.kind > 0).sum(0)]
        return self.__dict__["_slot_use"]

    def _jones(self) -> dict:
        """Geometry-only factors of the polarisation chain (cached), in each interaction's own basis.

        The field before slot i is (v0, v1) on (s_i, p_in_i); the slot maps it to (c_te v0, c_tm v1) on
        (s_i, p_out_i); paths that go on project that onto (s_{i+1}, p_in_{i+1}) with `step[i]`
        [n_{i+1}, 4] (s.s', p_out.s', s.p_in', p_out.p_in'), the others onto e_R with `end[i]` [n_i - n_{i+1}, 2].
        `start` [n_0, 2]: e_T on (s_0, p_in_0); `direct` [Q - n_0]: e_T . e_R of paths with no interaction."""
        if "_jones_cache" not in self.__dict__:
            use = [n for n in self.slot_use() if n > 0]
            c = lambda x: x.to(torch.complex128).contiguous()  # noqa: E731
            dot = lambda x, y: (x * y).sum(-1)  # noqa: E731
            step, end = [], []
            for i, n in enumerate(use):
                s, pout = self.s[:n, i], self.p_out[:n, i]
                nxt = use[i + 1] if i + 1 < len(use) else 0
                if nxt:
                    s2, p2 = self.s[:nxt, i + 1], self.p_in[:nxt, i + 1]
                    step.append(c(torch.stack([dot(s[:nxt], s2), dot(pout[:nxt], s2), dot(s[:nxt], p2),
                                               dot(pout[:nxt], p2)], 1)))
                er = self.e_rx[nxt:n]
                end.append(c(torch.stack([dot(s[nxt:], er), dot(pout[nxt:], er)], 1)))
            n0 = use[0] if use else 0
            start = c(torch.stack([dot(self.e_tx[:n0], self.s[:n0, 0]), dot(self.e_tx[:n0], self.p_in[:n0, 0])], 1)) \
                if n0 else torch.zeros((0, 2), dtype=torch.complex128)
            direct = c(dot(self.e_tx[n0:], self.e_rx[n0:]))
            self.__dict__["_jones_cache"] = {"use": use, "step": step, "end": end, "start": start,
                                             "direct": direct}
        return self.__dict__["_jones_cache"]

    def _free_space(self) -> torch.Tensor:
        """[Q] complex: each path's free-space factor sqrt(G_T G_R) lambda / (4 pi L) exp(-j k L) at its link's
        frequency (cached; the one factor of the chain that depends on the frequency besides the coefficients)."""
        if "_free_space_cache" not in self.__dict__:
            f = self.freq_hz[self.link]
            k0 = 2 * math.pi * f / C0
            self.__dict__["_free_space_cache"] = (self.gain * C0 / f / (4 * math.pi * self.length_m)).to(
                torch.complex128) * torch.exp(-1j * k0 * self.length_m)
        return self.__dict__["_free_space_cache"]

    def at_frequency(self, freq_hz) -> "RoomPaths":
        """The same paths evaluated at freq_hz (a number [Hz] for every link, or [M] one per link): the traced
        geometry and its frequency-free caches (slot use, the polarisation chain's projections) are shared."""
        f = torch.as_tensor(np.asarray(freq_hz, dtype=np.float64))
        f = f.expand(self.num_links).clone() if f.ndim == 0 else f
        if f.shape != (self.num_links,):
            raise ValueError(f"freq_hz: expected one frequency or {self.num_links}, got shape {tuple(f.shape)}")
        out = RoomPaths(self.num_links, self.link, self.length_m, self.gain, self.order, self.e_tx, self.e_rx,
                        self.kind, self.patch, self.cos, self.s, self.p_in, self.p_out, f)
        for key in ("_slot_use", "_jones_cache"):
            if key in self.__dict__:
                out.__dict__[key] = self.__dict__[key]
        return out

    def select_links(self, rows) -> "RoomPaths":
        """The paths of links `rows` (renumbered 0..len(rows)-1 in that order)."""
        rows, keep, new_link = renumber_links(self.link, self.num_links, rows)
        return RoomPaths(int(rows.numel()), new_link, *(t[keep] for t in (
            self.length_m, self.gain, self.order, self.e_tx, self.e_rx, self.kind, self.patch, self.cos, self.s,
            self.p_in, self.p_out)), self.freq_hz[rows])

    def select_paths(self, keep: torch.Tensor) -> "RoomPaths":
        """The paths where keep [Q] bool is true, every link kept (their order, most interactions first, too)."""
        return RoomPaths(self.num_links, *(t[keep] for t in (
            self.link, self.length_m, self.gain, self.order, self.e_tx, self.e_rx, self.kind, self.patch, self.cos,
            self.s, self.p_in, self.p_out)), self.freq_hz)

    def small_third_order(self, area_m2: np.ndarray, third_order_min_area_m2: float) -> torch.Tensor:
        """[Q] bool: the paths of order 3 and up with a reflection off a patch under third_order_min_area_m2
        (area_m2 [P] of every patch): those third_order_small_reflections adds."""
        small = torch.as_tensor(np.asarray(area_m2) < third_order_min_area_m2)[self.patch] & (self.kind == 1)
        return (self.order >= 3) & small.any(1)

    def field(self, eta_of_patch: torch.Tensor, thickness_of_patch: torch.Tensor | None,
              scattering_of_patch: torch.Tensor, incoherent: bool = False) -> torch.Tensor:
        """Received complex amplitude [M] (P_T = 1 W), every coefficient evaluated exactly (incoherent: the sum of
        the paths' powers [M] W instead, chain).

        eta_of_patch [P, M] complex relative permittivity of each patch's material at each link's
        frequency (or [P, 1] for one frequency); thickness_of_patch [P] m (None: half-spaces);
        scattering_of_patch [P] S."""
        f = self.freq_hz[self.link]
        k0 = (2 * math.pi * f / C0)[:, None]
        col = self.link if eta_of_patch.shape[1] > 1 else torch.zeros_like(self.link)
        eta = eta_of_patch[self.patch, col[:, None]]                                  # [Q, I]
        th = None if thickness_of_patch is None else thickness_of_patch[self.patch]
        r_te, r_tm = fresnel(eta, self.cos, k0, th)
        if th is None:
            t_te = t_tm = torch.zeros_like(r_te)             # a half-space transmits nothing
        else:
            t_te, t_tm = slab_transmission(eta, self.cos, k0, th)
        refl = self.kind == 1
        c_te, c_tm = torch.where(refl, r_te, t_te), torch.where(refl, r_tm, t_tm)
        spec = torch.where(refl, specular_share(scattering_of_patch[self.patch]),
                           torch.ones((), dtype=torch.float64)).prod(1)
        return self.chain([(c_te[:, i], c_tm[:, i]) for i in range(c_te.shape[1])], spec, incoherent)

    def chain(self, coefficients: list, spec: torch.Tensor, incoherent: bool = False) -> torch.Tensor:
        """Received complex amplitude [M] from the TE and TM coefficients of each interaction slot i,
        coefficients[i] = (c_te, c_tm) complex of length >= slot_use()[i] (the paths using slot i come
        first), and each path's specular share spec [Q] (prod sqrt(1 - S^2)). The field vector of the
        module docstring is carried as its two components in each interaction's basis (`_jones`).
        incoherent: the sum of the paths' powers sum_p |a_p|^2 [M] W (P_T = 1 W) instead, no phases (the
        band's "incoherent" sum, room.BANDS)."""
        j = self._jones()
        pieces = []
        if j["use"]:
            v0, v1 = j["start"][:, 0], j["start"][:, 1]
            for i, n in enumerate(j["use"]):
                c_te, c_tm = coefficients[i]
                w0, w1 = c_te[:n] * v0, c_tm[:n] * v1
                nxt = j["step"][i].shape[0] if i < len(j["step"]) else 0
                e = j["end"][i]
                pieces.append(e[:, 0] * w0[nxt:] + e[:, 1] * w1[nxt:])
                if nxt:
                    st = j["step"][i]
                    v0 = st[:, 0] * w0[:nxt] + st[:, 1] * w1[:nxt]
                    v1 = st[:, 2] * w0[:nxt] + st[:, 3] * w1[:nxt]
        pol = torch.cat(pieces[::-1] + [j["direct"]])
        a = self._free_space() * spec * pol
        if incoherent:
            return torch.zeros(self.num_links, dtype=torch.float64).index_add(0, self.link, abs2(a))
        return torch.zeros(self.num_links, dtype=torch.complex128).index_add(0, self.link, a)


# ---------------------------------------------------------------------------------------------------
# tracing the paths
# ---------------------------------------------------------------------------------------------------
SOURCE_ROWS = 2_000_000   # (transmitter, sequence) rows built at once: a group of transmitters at a time


def reflection_paths(tx: np.ndarray, rx: np.ndarray, patches: PatchSet, cand: np.ndarray, order: int,
                     min_m: float = 1e-4, small: np.ndarray | None = None,
                     max_small: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """_transmitter_paths (below) for groups of distinct transmitters at a time, so that the rows of candidate
    sequences held at once stay near SOURCE_ROWS (transmitters x candidates^order): third order off a hundred
    patches from a survey's hundred transmitter positions is about 10^8 rows, tens of GB at once. Same returns,
    ordered by patch sequence, then link."""
    tx = np.asarray(tx, dtype=np.float64)
    sources, link_source = np.unique(tx, axis=0, return_inverse=True)
    link_source = link_source.reshape(-1)
    group = max(1, SOURCE_ROWS // max(1, len(cand)) ** order)
    if len(sources) <= group:
        return _transmitter_paths(tx, rx, patches, cand, order, min_m, small, max_small)
    rx = np.asarray(rx, dtype=np.float64)
    parts = []
    for g0 in range(0, len(sources), group):
        sel = np.flatnonzero((link_source >= g0) & (link_source < g0 + group))
        link, seq, pts = _transmitter_paths(tx[sel], rx[sel], patches, cand, order, min_m, small, max_small)
        parts.append((sel[link], seq, pts))
    links = np.concatenate([p[0] for p in parts])
    seq = np.concatenate([p[1] for p in parts]).reshape(-1, order)
    pts = np.concatenate([p[2] for p in parts]).reshape(-1, order, 3)
    srt = np.lexsort([links] + [seq[:, k] for k in range(order - 1, -1, -1)])
    return links[srt], seq[srt], pts[srt]


def _transmitter_paths(tx: np.ndarray, rx: np.ndarray, patches: PatchSet, cand: np.ndarray, order: int,
                       min_m: float = 1e-4, small: np.ndarray | None = None,
                       max_small: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Specular paths Tx -> patch_1 -> ... -> patch_order -> Rx over sequences of `cand` (no patch twice in a
    row, nor a patch and one coplanar with it). small [len(cand)] bool: candidates of which a sequence may hold
    at most `max_small` (None: no limit).

    Returns (link [N], patch sequence [N, order], reflection points [N, order, 3]), ordered by patch
    sequence, then link. Images of the transmitter are built forward, for every distinct transmitter and
    sequence at once (rows (transmitter, sequence)), then spread over the transmitter's links; the
    reflection points are found backward from the receiver, and each must lie on its patch with the
    previous vertex on the same side as the image's pre-image."""
    nrm, pnt = patches.normal, patches.point
    cn, cp = nrm[cand], pnt[cand]
    offset = (cp * cn).sum(1)
    if order > 1:
        coplanar = (np.abs(cn @ cn.T) > 0.999) & (
            np.abs(((cp[None, :, :] - cp[:, None, :]) * cn[:, None, :]).sum(2)) < 1e-3)
    tx = np.asarray(tx, dtype=np.float64)
    rx = np.asarray(rx, dtype=np.float64)
    # the images depend on the transmitter and the sequence only: built once per distinct transmitter (a radio
    # map's links share one), rows (transmitter, sequence), then spread over each transmitter's links
    sources, link_source = np.unique(tx, axis=0, return_inverse=True)
    link_source = link_source.reshape(-1)
    source = np.arange(len(sources))
    seq = np.zeros((len(sources), 0), np.int64)          # indices into cand
    num_small = np.zeros(len(sources), np.int64)         # small candidates in each row's sequence
    images = [sources]
    side_last = np.zeros(0)
    for level in range(order):
        # the image must not lie on the plane: screened for every (row, candidate) with a matrix product and half
        # the margin, then decided exactly on the rows kept
        side = images[-1] @ cn.T - offset                                      # [R, K]
        ok = np.abs(side) > 0.5 * min_m
        if level:
            last = seq[:, -1]
            ok &= ~coplanar[last]
            ok[np.arange(len(last)), last] = False
        if small is not None:
            ok &= num_small[:, None] + small[None, :] <= max_small
        r, j = np.nonzero(ok)
        exact = np.abs(_dot(images[-1][r] - cp[j], cn[j])) > min_m
        r, j = r[exact], j[exact]
        side_last = side[r, j]
        if small is not None:
            num_small = num_small[r] + small[j]
        source, seq = source[r], np.concatenate([seq[r], j[:, None]], 1)
        images = [im[r] for im in images]
        images.append(mirror_points(images[-1], cp[j], cn[j]))
        if source.size == 0:
            break
    if order > 1 and source.size:
        # before pairing the rows with receivers, drop those no receiver can complete (most third-order rows)
        keep = _sequence_may_connect(images, cand[seq], patches)
        source, seq, side_last = source[keep], seq[keep], side_last[keep]
        images = [im[keep] for im in images]
    # every link of each row's transmitter with its receiver on the image's side of the last plane (screened with
    # half the margin, decided exactly below), in chunks of rows of at most PAIR_CHUNK (row, link) pairs: third
    # order off a few dozen large patches is tens of millions of pairs (a flat of four rooms), held at once 10 GB
    if source.size == 0:
        return np.zeros(0, np.int64), np.zeros((0, order), np.int64), np.zeros((0, order, 3))
    by_source = np.argsort(link_source, kind="stable")                   # the links of each transmitter in turn
    count = np.bincount(link_source, minlength=len(sources))
    first_link = np.cumsum(count) - count
    rep_all = count[source]
    rx_side = rx @ cn.T - offset                                           # [M, K], gathered per pair
    # what depends on the row alone (its planes, the images' offsets from them), once per row and reflection
    per_row = []
    for k in range(order):
        p_row = cand[seq[:, k]]
        n_row, q_row = nrm[p_row], pnt[p_row]
        per_row.append((p_row, n_row, q_row, _dot(images[k] - q_row, n_row), _dot(images[k + 1] - q_row, n_row)))
    chunk_of_row = (np.cumsum(rep_all) - rep_all) // PAIR_CHUNK          # by the pairs before the row: contiguous
    starts = np.flatnonzero(np.diff(chunk_of_row, prepend=-1))
    out = [_paths_of_rows(np.arange(r0, r1), rep_all, first_link, source, by_source, side_last, rx, rx_side, seq,
                          images, per_row, patches, order, min_m)
           for r0, r1 in zip(starts, np.append(starts[1:], len(source)))]
    out = [o for o in out if o[0].size]
    if not out:
        return np.zeros(0, np.int64), np.zeros((0, order), np.int64), np.zeros((0, order, 3))
    links = np.concatenate([o[0] for o in out])
    seq = np.concatenate([o[1] for o in out])
    pts = np.concatenate([o[2] for o in out])
    srt = np.lexsort([links] + [seq[:, k] for k in range(order - 1, -1, -1)])
    return links[srt], cand[seq[srt]], pts[srt]


def _angular_radius(radius: np.ndarray, distance: np.ndarray) -> np.ndarray:
    """Half-angle [rad] of the cone from a point at `distance` that holds a sphere of `radius`; pi from inside it."""
    return np.where(distance > radius, np.arcsin(np.clip(radius / np.maximum(distance, 1e-12), 0.0, 1.0)), math.pi)


def _sequence_may_connect(images: list[np.ndarray], seq_patch: np.ndarray, patches: PatchSet) -> np.ndarray:
    """[R] bool: whether rows (transmitter, patch sequence) can hold a path for some receiver. images: order + 1
    arrays [R, 3], the transmitter and its images across seq_patch [R, order] in turn.

    Reflection point k lies on the segment from image k + 1 to reflection point k + 1, so the ray from that image
    through patch k must reach patch k + 1: with each patch in its bounding sphere, the angle at the image between
    the spheres' centres must not exceed the sum of the spheres' angular radii. A necessary condition (no path
    is lost), decided once per row instead of once per (row, receiver) pair."""
    ok = np.ones(len(seq_patch), dtype=bool)
    for k in range(seq_patch.shape[1] - 1):
        image = images[k + 1]
        c_a, r_a = patches.bounding_spheres(seq_patch[:, k])
        c_b, r_b = patches.bounding_spheres(seq_patch[:, k + 1])
        a, b = c_a - image, c_b - image
        d_a, d_b = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
        spread = _angular_radius(r_a, d_a) + _angular_radius(r_b, d_b)
        cos_ab = _dot(a, b) / np.maximum(d_a * d_b, 1e-24)
        # a thousandth of a radian of slack: rounding never drops a path at the edge of a patch
        ok &= (spread + 1e-3 >= math.pi) | (cos_ab >= np.cos(np.minimum(spread + 1e-3, math.pi)))
    return ok


def _paths_of_rows(rows, rep_all, first_link, source, by_source, side_last, rx, rx_side, seq, images, per_row,
                   patches: PatchSet, order: int, min_m: float):
    """(link [N], sequence of candidate indices [N, order], reflection points [N, order, 3]) of the rows
    (transmitter, sequence) `rows` of reflection_paths, each with every link of its transmitter."""
    rep = rep_all[rows]
    row = np.repeat(rows, rep)
    within = np.arange(len(row)) - np.repeat(np.cumsum(rep) - rep, rep)
    links = by_source[first_link[source[row]] + within]
    keep = side_last[row] * rx_side[links, seq[row, -1]] > 0.5 * min_m ** 2
    row, links = row[keep], links[keep]
    # backwards from the receiver, for the (row, link) pairs still in play
    pts = []
    x = rx[links]
    for k in range(order - 1, -1, -1):
        if links.size == 0:
            break
        p_row, n_row, q_row, pre_side, img_side = per_row[k]
        n_, q_ = n_row[row], q_row[row]
        x_side = _dot(x - q_, n_)
        ok = x_side * pre_side[row] > min_m ** 2
        row, links, x, x_side = row[ok], links[ok], x[ok], x_side[ok]
        pts = [q[ok] for q in pts]
        a = images[k + 1][row]
        da = img_side[row]
        f = da / np.where(np.abs(da - x_side) > 1e-15, da - x_side, 1e-15)
        c = a + f[:, None] * (x - a)                           # where the leg image -> x crosses the plane
        ok = patches.contains(p_row[row], c)
        row, links, x = row[ok], links[ok], c[ok]
        pts = [q[ok] for q in pts]
        pts.insert(0, x)
    if links.size == 0:
        return np.zeros(0, np.int64), np.zeros((0, order), np.int64), np.zeros((0, order, 3))
    return links, seq[row], np.stack(pts, 1)


def _basis(k: np.ndarray, n: np.ndarray, reflect: np.ndarray):
    """(cos, s, p_in, p_out) of interactions with incoming unit directions k and normals n [N, 3]: the TE direction s
    and the TM ones before and after (rfir_core.physics.polarisation.reflection_basis)."""
    k_out = np.where(reflect[:, None], mirror_direction(k, n), k)
    return (np.abs(_dot(k, n)), *reflection_basis(k, n, k_out))


def trace_room_paths(tx_m, rx_m, freq_hz, patches: PatchSet, provider, *, polarisation: str = "V",
                     max_order: int = MAX_ORDER, higher_order_min_area_m2: float = HIGHER_ORDER_MIN_AREA_M2,
                     first_order_min_area_m2: float = 0.0, third_order_min_area_m2: float = THIRD_ORDER_MIN_AREA_M2,
                     max_interactions: int = MAX_INTERACTIONS,
                     third_order_small_reflections: int = THIRD_ORDER_SMALL_REFLECTIONS,
                     tx_gain=None, rx_gain=None, tx_field=None, rx_field=None, tx_axes=None, rx_axes=None) -> RoomPaths:
    """Every specular path up to `max_order` reflections of links tx_m, rx_m [M, 3] m, to be evaluated at freq_hz
    [M] Hz (the tracing does not depend on it: RoomPaths.at_frequency evaluates the paths at any other).

    First-order reflections use every patch of at least first_order_min_area_m2, second order the
    patches of at least higher_order_min_area_m2 (walls, floor, ceiling, large furniture), third and
    higher orders those of at least third_order_min_area_m2 (the surfaces that bound a room), of which up to
    third_order_small_reflections reflections may be off patches of at least higher_order_min_area_m2 (a desk
    top between the room's surfaces).
    tx_gain / rx_gain: callables (unit directions [N, 3] leaving the antenna: the first leg's, the last leg's
    reversed) -> linear power gain [N]; None: isotropic. tx_field / rx_field: callables (unit directions [N, 3] of
    travel) -> unit field directions [N, 3] of the antenna (a tilted dipole's); None: `polarisation`'s. tx_axes /
    rx_axes [M, 3]: each link's antenna axis, passed to that end's callables as a second argument (one per direction).
    Paths with more than max_interactions interactions (reflections plus surfaces crossed) are dropped."""
    tx = np.asarray(tx_m, dtype=np.float64)
    rx = np.asarray(rx_m, dtype=np.float64)
    m_links = len(tx)
    link, order, verts, refl = [np.arange(m_links)], [np.zeros(m_links, np.int64)], [], []
    verts.append(np.stack([tx, rx], 1))                       # [N, order + 2, 3] per order
    refl.append(np.zeros((m_links, 0), np.int64))
    for o in range(1, max_order + 1):
        small = None
        if o <= 2:
            cand = np.flatnonzero(patches.area >= (first_order_min_area_m2, higher_order_min_area_m2)[o - 1])
        elif third_order_small_reflections > 0:
            cand = np.flatnonzero(patches.area >= min(higher_order_min_area_m2, third_order_min_area_m2))
            small = patches.area[cand] < third_order_min_area_m2
        else:
            cand = np.flatnonzero(patches.area >= third_order_min_area_m2)
        lo, po, co = reflection_paths(tx, rx, patches, cand, o, small=small, max_small=third_order_small_reflections)
        link.append(lo)
        order.append(np.full(len(lo), o))
        verts.append(np.concatenate([tx[lo][:, None], co, rx[lo][:, None]], 1))
        refl.append(po)
    # legs of every path: (path, leg index, start, end, patches at its two ends (-1: an antenna))
    q0 = 0
    leg_path, leg_idx, leg_a, leg_b, skip_a, skip_b, length, k_dep, k_arr = [], [], [], [], [], [], [], [], []
    for o, (v, r) in enumerate(zip(verts, refl)):
        n = len(v)
        ends = np.concatenate([np.full((n, 1), -1), r, np.full((n, 1), -1)], 1)
        for i in range(o + 1):
            leg_path.append(q0 + np.arange(n))
            leg_idx.append(np.full(n, i))
            leg_a.append(v[:, i])
            leg_b.append(v[:, i + 1])
            skip_a.append(ends[:, i])
            skip_b.append(ends[:, i + 1])
        seg = np.diff(v, axis=1)
        length.append(np.linalg.norm(seg, axis=2).sum(1))
        k_dep.append(seg[:, 0])
        k_arr.append(seg[:, -1])
        q0 += n
    link, order = np.concatenate(link), np.concatenate(order)
    leg_path, leg_idx = np.concatenate(leg_path), np.concatenate(leg_idx)
    leg_a, leg_b = np.concatenate(leg_a), np.concatenate(leg_b)
    skip_a, skip_b = np.concatenate(skip_a), np.concatenate(skip_b)
    length = np.concatenate(length)
    unit = lambda x: x / np.linalg.norm(x, axis=1, keepdims=True).clip(1e-12)  # noqa: E731
    k_dep, k_arr = unit(np.concatenate(k_dep)), unit(np.concatenate(k_arr))
    cl, cp, cf = leg_crossings(provider, patches, leg_a, leg_b, skip_a, skip_b)
    # interactions in path order: crossings (key: leg + fraction) and reflections (key: leg + 1)
    dirs = unit(leg_b - leg_a)
    end = skip_b >= 0
    ip = np.concatenate([leg_path[cl], leg_path[end]])
    ik = np.concatenate([leg_idx[cl] + cf, leg_idx[end] + 1.0])
    ipatch = np.concatenate([cp, skip_b[end]])
    ikind = np.concatenate([np.full(len(cl), 2), np.ones(int(end.sum()), np.int64)])
    idir = np.concatenate([dirs[cl], dirs[end]])
    srt = np.lexsort((ik, ip))
    ip, ipatch, ikind, idir = ip[srt], ipatch[srt], ikind[srt], idir[srt]
    q_n = len(link)
    counts = np.bincount(ip, minlength=q_n)
    keep_path = counts <= max_interactions
    slot = np.arange(len(ip)) - np.repeat(np.cumsum(counts) - counts, counts)
    width = max(1, int(counts[keep_path].max()) if keep_path.any() else 1)
    cos, s, pin, pout = _basis(idir, patches.normal[ipatch], ikind == 1)
    kind = np.zeros((q_n, width), np.int64)
    patch = np.zeros((q_n, width), np.int64)
    cosm = np.ones((q_n, width))
    sm, pim, pom = (np.zeros((q_n, width, 3)) for _ in range(3))
    ok = keep_path[ip]
    at = (ip[ok], slot[ok])
    kind[at], patch[at], cosm[at] = ikind[ok], ipatch[ok], cos[ok]
    sm[at], pim[at], pom[at] = s[ok], pin[ok], pout[ok]
    gain = np.ones(q_n)
    at_tx, at_rx = (() if a is None else (np.asarray(a, np.float64)[link],) for a in (tx_axes, rx_axes))  # per path
    if tx_gain is not None:
        gain = gain * np.asarray(tx_gain(k_dep, *at_tx), dtype=np.float64)
    if rx_gain is not None:
        gain = gain * np.asarray(rx_gain(-k_arr, *at_rx), dtype=np.float64)
    e_tx = antenna_polarisation(k_dep, polarisation) if tx_field is None else np.asarray(tx_field(k_dep, *at_tx), np.float64)
    e_rx = antenna_polarisation(k_arr, polarisation) if rx_field is None else np.asarray(rx_field(k_arr, *at_rx), np.float64)
    # paths sorted by interaction count, most first: slot i is then used by a prefix of the paths
    order_q = np.flatnonzero(keep_path)[np.argsort(-counts[keep_path], kind="stable")]
    t = lambda x: torch.as_tensor(np.ascontiguousarray(x[order_q]))  # noqa: E731
    return RoomPaths(m_links, t(link), t(length), t(np.sqrt(gain)), t(order), t(e_tx), t(e_rx), t(kind), t(patch),
                     t(cosm), t(sm), t(pim), t(pom), torch.as_tensor(np.asarray(freq_hz, dtype=np.float64)))
