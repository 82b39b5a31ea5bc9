"""Diffuse scattering in rooms, summed in power over cells of surfels (docs/physics.md sections 8.8 and 8.10).

The Lambertian term of section 8.8 for every link and every lit cell:

    P_diff = sum_c G_T G_R S_m^2 |Gamma_m(theta_c)|^2 A_c cos(theta_i) cos(theta_o) lambda^2 V_c / (16 pi^3 d_i^2 d_o^2)

Diffuse power varies slowly over a surface, so the surfels of each patch are grouped into cells of
about `cell_m` (a voxel grid on the patch): each cell has the summed area, the area-weighted centre
and the patch's normal, and its visibility V_c = V_tx V_rx is traced to the cell's surfel nearest that
centre. |Gamma|^2 is the mean of |R_TE|^2 and |R_TM|^2 (the diffuse part has no definite
polarisation). Everything but the materials is summed once into per-(link, material, angle node)
weights, so a fit step costs M x materials x nodes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from rfir_stages.po.geometry import single_thread_torch
from rfir_stages.rf_fit.occlusion import ShellSplitOcclusion, TracerOcclusion

from .materials import C0, fresnel
from .room_paths import PatchSet, _dot

NODES = 46   # incidence-angle nodes 0, 2, ..., 90 degrees; |Gamma|^2 is linear between them


@dataclass
class DiffuseCells:
    """centre [C, 3], normal [C, 3], area [C] m^2, material [C] int64, anchor [C] surfel used for visibility."""

    centre: np.ndarray
    normal: np.ndarray
    area: np.ndarray
    material: np.ndarray
    anchor: np.ndarray


def diffuse_cells(means: np.ndarray, areas_m2: np.ndarray, patches: PatchSet, material_of_patch: np.ndarray,
                  cell_m: float) -> DiffuseCells:
    """Group each patch's surfels into cells of about cell_m (a voxel grid)."""
    p = patches.surfel_patch
    vox = np.floor(means / cell_m).astype(np.int64)
    key = np.concatenate([p[:, None], vox], 1)
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    c = len(uniq)
    area = np.bincount(inv, weights=areas_m2, minlength=c)
    centre = np.stack([np.bincount(inv, weights=areas_m2 * means[:, i], minlength=c) for i in range(3)], 1)
    centre /= np.maximum(area, 1e-30)[:, None]
    dist = np.linalg.norm(means - centre[inv], axis=1)
    order = np.lexsort((dist, inv))
    first = order[np.unique(inv[order], return_index=True)[1]]
    patch = uniq[:, 0]
    return DiffuseCells(centre, patches.normal[patch], area, material_of_patch[patch], first)


@dataclass
class DiffuseTerms:
    """weight [M, N, NODES]: sum over cells of material n of the geometric factor, spread on the nodes."""

    weight: torch.Tensor
    freq_hz: torch.Tensor

    def select_links(self, rows) -> "DiffuseTerms":
        rows = torch.as_tensor(np.asarray(rows), dtype=torch.int64)
        return DiffuseTerms(self.weight[rows], self.freq_hz[rows])

    def power(self, eta_of_material: torch.Tensor, thickness_m: torch.Tensor | None,
              scattering: torch.Tensor) -> torch.Tensor:
        """P_diff [M] W (P_T = 1 W) for materials' eta [N, 1] (one frequency) or [N, M], thickness [N], S [N]."""
        g2 = diffuse_reflectance(eta_of_material, thickness_m, scattering, self.freq_hz)
        if eta_of_material.shape[1] == 1:
            return (self.weight * g2[None]).sum((1, 2))
        return (self.weight * g2.permute(1, 0, 2)).sum((1, 2))


def diffuse_reflectance(eta_of_material: torch.Tensor, thickness_m: torch.Tensor | None, scattering: torch.Tensor,
                        freq_hz: torch.Tensor) -> torch.Tensor:
    """|Gamma|^2 S^2 on the NODES incidence angles: [N, NODES] for eta [N, 1] (one frequency, freq_hz[0]) or
    [N, M, NODES] for eta [N, M] at the links' freq_hz [M]; |Gamma|^2 = (|R_TE|^2 + |R_TM|^2) / 2, S [N],
    thickness [N] m (None: half-spaces)."""
    cos = torch.cos(torch.deg2rad(torch.linspace(0.0, 90.0, NODES, dtype=torch.float64)))
    if eta_of_material.shape[1] == 1:
        k0 = 2 * math.pi * freq_hz[:1] / C0
        th = None if thickness_m is None else thickness_m[:, None]
        r_te, r_tm = fresnel(eta_of_material, cos[None], k0[None], th)                    # [N, NODES]
        return 0.5 * (r_te.abs() ** 2 + r_tm.abs() ** 2) * (scattering ** 2)[:, None]
    k0 = 2 * math.pi * freq_hz / C0                                                          # [M]
    th = None if thickness_m is None else thickness_m[:, None, None]
    r_te, r_tm = fresnel(eta_of_material[:, :, None], cos[None, None], k0[None, :, None], th)  # [N, M, NODES]
    return 0.5 * (r_te.abs() ** 2 + r_tm.abs() ** 2) * (scattering ** 2)[:, None, None]


class CellVisibility:
    """Transmittance from points to every diffuse cell (to its anchor surfel), kept per point.

    It depends on the point and the geometry only, not on the other end of a link: a radio map's
    receivers are traced once per model and every later transmitter reuses them (the largest part of
    a map's cost on furniture-resolving surfels). Only the entries a call needs are traced (a cell
    with the link's ends on opposite sides of its plane scatters nothing between them, whatever its
    visibility); the others are traced when a later call needs them. Rows are kept up to max_bytes,
    the oldest dropped first; points are keyed rounded to 1 nm.

    Large batches are traced with the provider's shell split (rf_fit.occlusion.ShellSplitOcclusion:
    the same transmittances to rounding, the room's walls, floor and ceiling traced only where a
    segment comes near them), segment after segment to one cell from every point (rays with nearby
    ends in turn walk the same part of the BVH)."""

    SPLIT_MIN_SEGMENTS = 20_000   # below this the shell split's set-up (two more BVHs) costs more than it saves

    def __init__(self, cells: DiffuseCells, provider, opacity: float, margin_m: float, t_stop: float,
                 max_bytes: float = 256e6):
        self.cells, self.provider = cells, provider
        self.margin_m, self.t_stop = float(margin_m), float(t_stop)
        self.op = torch.full((provider.geom.num,), float(opacity), dtype=torch.float64)
        self.max_rows = max(1, int(max_bytes // max(1, 8 * len(cells.area))))
        self._rows: dict[bytes, np.ndarray] = {}     # NaN: not traced yet
        self._split = None

    def _provider_for(self, num_segments: int):
        """The provider to trace num_segments segments with (the shell split built on first use)."""
        provider = self.provider
        # the split is measured on the CPU tracer (bench/bench_rssi.py); a GPU's tracer is left as it is
        if (num_segments >= self.SPLIT_MIN_SEGMENTS and isinstance(provider, TracerOcclusion)
                and provider.device.type == "cpu"):
            if self._split is None:
                with single_thread_torch():   # small tensor ops: thread hand-offs cost more than the work
                    self._split = ShellSplitOcclusion(provider)
            provider = self._split
        return provider

    def _segments(self, points: np.ndarray, cells: np.ndarray) -> np.ndarray:
        """V [Q] from points [Q, 3] to the anchors of cells [Q]."""
        v = self._provider_for(len(cells)).segment_transmittance(
            torch.as_tensor(points), torch.as_tensor(self.cells.anchor[cells]), self.margin_m, self.op, self.t_stop)
        return v.numpy()

    def __call__(self, points: np.ndarray, need: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(V [U, C] of the distinct points, index [N] of each point's row).

        need [N, C] bool: the entries each point needs (None: all); entries no point needs and not traced
        before are 0 in V."""
        c = len(self.cells.area)
        uniq, inv = np.unique(np.round(points, 9), axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        keys = [u.tobytes() for u in uniq]
        out = np.full((len(keys), c), np.nan)
        new = []
        for i, k in enumerate(keys):
            row = self._rows.get(k)
            if row is None:
                new.append(i)
            else:
                out[i] = row
        if need is None:
            missing = np.isnan(out)
        else:
            missing = _rows_any(np.asarray(need, dtype=bool), inv, len(keys)) & np.isnan(out)
        cell, row = np.nonzero(np.ascontiguousarray(missing.T))    # cell after cell, each from every point
        if len(cell):
            out[row, cell] = self._segments(uniq[row], cell)
        old = [i for i in np.flatnonzero(missing.any(1)) if keys[i] in self._rows]    # kept rows traced further
        self._rows.update((keys[i], out[i].copy()) for i in old)
        if new and len(new) <= self.max_rows:
            if len(self._rows) + len(new) > self.max_rows:
                mine = set(keys)
                for k in [k for k in self._rows if k not in mine][:len(self._rows) // 2 + len(new)]:
                    del self._rows[k]
            self._rows.update((keys[i], out[i].copy()) for i in new)
        return np.nan_to_num(out, nan=0.0), inv

    def __len__(self) -> int:
        """Points kept."""
        return len(self._rows)

    def clear(self) -> None:
        self._rows.clear()

    def keep(self, points: np.ndarray, rows: np.ndarray) -> None:
        """Keep rows V [U, C] of points [U, 3] traced elsewhere with the same geometry and settings (a model's
        stored map receivers; RoomGeometry.visibility_key says when they apply)."""
        for p, r in zip(np.round(np.asarray(points, np.float64), 9), np.asarray(rows, np.float64)):
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


def _cell_factors(tx: np.ndarray, rx: np.ndarray, lam2: np.ndarray, cells: DiffuseCells):
    """Per (link, cell) of links tx, rx [B, 3] m at wavelengths^2 lam2 [B] m^2: (g [B, C] the Lambertian factor
    A cos(theta_i) cos(theta_o) lambda^2 / (16 pi^3 d_i^2 d_o^2) of section 8.8 without V, 0 where the ends lie
    on opposite sides of the cell; node [B, C] int64 and frac [B, C]: theta_i between angle nodes node and
    node + 1)."""
    wi = tx[:, None, :] - cells.centre[None]                        # [B, C, 3]
    wo = rx[:, None, :] - cells.centre[None]
    n = cells.normal[None]
    di2, do2 = _dot(wi, wi), _dot(wo, wo)
    di, do = np.sqrt(di2), np.sqrt(do2)
    ci = _dot(wi, n) / di
    co = _dot(wo, n) / do
    lit = ci * co > 0                                                  # both ends on one side
    ci, co = np.abs(ci), np.abs(co)
    g = (cells.area[None] * ci * co * lam2[:, None] / (16 * math.pi ** 3 * di ** 2 * do ** 2)) * lit
    theta = np.arccos(np.clip(ci, 0.0, 1.0)) / math.radians(90.0 / (NODES - 1))
    node = np.clip(np.floor(theta).astype(np.int64), 0, NODES - 2)
    return g, node, np.clip(theta - node, 0.0, 1.0)


def diffuse_terms(tx_m: np.ndarray, rx_m: np.ndarray, freq_hz: np.ndarray, cells: DiffuseCells, num_materials: int,
                  provider, opacity: float, margin_m: float, t_stop: float, link_chunk: int = 256,
                  progress_task=None, visibility: CellVisibility | None = None) -> DiffuseTerms:
    """The weights of DiffuseTerms for links tx_m, rx_m [M, 3] at freq_hz [M] (isotropic antennas).

    visibility: a CellVisibility of these cells, provider and settings to reuse (None: a fresh one)."""
    tx = np.asarray(tx_m, dtype=np.float64)
    rx = np.asarray(rx_m, dtype=np.float64)
    m = len(tx)
    if visibility is None:
        visibility = CellVisibility(cells, provider, opacity, margin_m, t_stop)
    # each end's visibility is needed only where the cell is lit (both ends on one side of its plane, the loop's
    # test below): here from the ends' heights over the planes, with those within 1 nm of a plane kept (rounding
    # differs from the loop's), so every lit entry is traced
    offset = (cells.centre * cells.normal).sum(1)
    h_tx, h_rx = tx @ cells.normal.T - offset, rx @ cells.normal.T - offset                 # [M, C] m
    need = (h_tx * h_rx > 0) | (np.abs(h_tx) < 1e-9) | (np.abs(h_rx) < 1e-9)
    v_tx, i_tx = visibility(tx, need)
    lam2 = (C0 / np.asarray(freq_hz, dtype=np.float64)) ** 2
    v_rx, i_rx = visibility(rx, need)
    weight = np.zeros((m, num_materials, NODES))
    size = num_materials * NODES
    for lo in range(0, m, link_chunk):
        hi = min(m, lo + link_chunk)
        g, node, frac = _cell_factors(tx[lo:hi], rx[lo:hi], lam2[lo:hi], cells)
        g = g * v_tx[i_tx[lo:hi]] * v_rx[i_rx[lo:hi]]
        b = hi - lo
        at = ((np.arange(b)[:, None] * num_materials + cells.material[None]) * NODES + node).ravel()
        # one pass in this order: the lower node's shares, then the upper node's (the sums of two index_add_)
        weight[lo:hi] = np.bincount(np.concatenate([at, at + 1]), np.concatenate([(g * (1 - frac)).ravel(),
                                    (g * frac).ravel()]), minlength=b * size).reshape(b, num_materials, NODES)
        if progress_task is not None:
            progress_task.advance(hi - lo)
    return DiffuseTerms(torch.from_numpy(weight), torch.as_tensor(np.asarray(freq_hz, dtype=np.float64)))
