"""The physical model of received power in rooms (docs/physics.md section 8.10): paths + diffuse + materials.

    P(link) = g |sum_paths a_path(materials)|^2 + g P_diff(materials)

with the specular paths of room_paths (direct path through slabs, reflections of order 1..N) and the
diffuse power of room_diffuse; g a system gain (1 unless fitted). Materials are those of
physical.MaterialParams (eps_r, sigma, thickness, S per material), one per label class by default
(desk_03 and desk_07 share "desk"), per label, per segment or one for the scene.

`RoomGeometry` holds what depends on the Gaussians only (patches, diffuse cells, the tracer);
`RoomLinks` what depends on a link set too; `RoomLinks.power` has the interface
fit_physical.fit_materials expects, so the fit (starts, start switching, best state) is shared with RCS.
"""
from __future__ import annotations

import copy
import hashlib
import math
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import torch

from rfir_core.errors import ConfigError
from rfir_core.physics.angle_nodes import AngleNodes
from rfir_core.threads import single_thread_torch
from .occlusion import FrozenGeometry, make_provider

from rfir_core.physics.materials import C0, ITU_MATERIALS, abs2, fresnel, slab_transmission, specular_share
from .antenna_patterns import LinkAxes, RoomAntennas
from .artifact import load_physical
from .device_gains import gains_at
from .links import geometry_from_artifact
from .physical import MaterialValues
from .plane_merge import SCATTER_FACTOR
from .radio_model_base import FLOOR_DB
from .room_diffuse import CROSSING_NODES, MAX_LEG_CROSSINGS, SMALL_PATCH_SHARE, CellCrossings, DiffuseCells, DiffuseTerms
from .room_diffuse import NODES as DIFFUSE_NODES
from .room_diffuse import diffuse_cells, diffuse_reflectance, diffuse_terms, diffuse_transmittance
from .room_paths import (CELL_PER_TILE, FOOTPRINT_REACH, HIGHER_ORDER_MIN_AREA_M2, MAX_INTERACTIONS, MAX_ORDER,
                         THIRD_ORDER_MIN_AREA_M2, THIRD_ORDER_SMALL_REFLECTIONS, TILE_CLOSING, PatchSet, RoomPaths,
                         build_patch_set, trace_room_paths)
from .surfels import surfel_areas


# rf_fit.room.scattering: one S for every material, or one per material
SCATTERING_CHOICES = ("shared", "per_material")
# rf_fit.room.band: how the paths of a link add up. "coherent": their complex amplitudes at the one frequency;
# "ble": the power of that sum averaged over the three BLE advertising channels (a BLE radio reports RSSI
# averaged over them); "incoherent": their powers |a_p|^2, no phases; "auto": chosen (rf_fit.room_stage).
BANDS = ("auto", "coherent", "ble", "incoherent")
BLE_CHANNELS_HZ = (2.402e9, 2.426e9, 2.480e9)
# the range [GHz] over which ITU-R P.2040 states its building materials' laws (eps_r = a f^b, sigma = c f^d; Table 3:
# concrete, plasterboard, wood, glass, ceiling board, chipboard, metal, 1-100 GHz), the form a fitted material's
# law takes: a room model predicts inside it (RoomPredictor.frequency_range_hz)
FITTED_LAW_RANGE_GHZ = (1.0, 100.0)


@dataclass
class RoomSettings:
    """[rf_fit.room] settings (configs/rf_fit.toml documents each)."""

    max_order: int = MAX_ORDER
    higher_order_min_area_m2: float = HIGHER_ORDER_MIN_AREA_M2
    third_order_min_area_m2: float = THIRD_ORDER_MIN_AREA_M2
    # reflections of a third-order path that may be off patches under third_order_min_area_m2 (down to
    # higher_order_min_area_m2: the desk tops)
    third_order_small_reflections: int = THIRD_ORDER_SMALL_REFLECTIONS
    # interactions per path at most, reflections and surfaces crossed alike (room_paths.MAX_INTERACTIONS)
    max_interactions: int = MAX_INTERACTIONS
    coplanar_m: float = 0.01
    # Gaussians scattered about their planes by more than coplanar_m / this are grouped by plane fit to this many times
    # their scatter (plane_merge; exact surfels have none and are joined at coplanar_m; 0: never)
    merge_scatter_factor: float = SCATTER_FACTOR
    # where a patch ends (room_paths.PATCH_EXTENTS): "disks" around each surfel, or "tiles", its own tile
    patch_extent: str = "tiles"
    diffuse: bool = True
    diffuse_cell_m: float = 0.7
    # patches smaller than this share of a diffuse cell pool their cells by material, facing and voxel (room_diffuse)
    small_patch_share: float = SMALL_PATCH_SHARE
    polarisation: str = "V"
    # the RF opacity stored with the model (rf/opacity, what attribute maps show); the room's paths and
    # diffuse legs are attenuated by the slab transmission of the surfaces they cross, not by opacity
    opacity: float = 0.9
    # the fit uses at most this many training links, evenly spaced (0: all): materials are a few
    # parameters each, and a fit step costs paths x interactions
    fit_links: int = 1500
    # the starting materials carried to the end of the fit (fit_physical.PhysicalFitConfig.starts_kept): a room's
    # dozen materials reach different optima from different starts
    starts_kept: int = 3
    # "shared": one scattering coefficient S for every material, fitted; "per_material": one each (RSSI links see
    # S mostly through the specular share sqrt(1 - S^2), which trades with |Gamma|: docs/physics.md 8.10)
    scattering: str = "shared"
    # a gain per transmitter / receiver / both, fitted under a zero-mean prior (device_gains.py)
    device_gains: str = "off"
    device_gain_prior_db: float = 3.0
    # the materials' |Gamma(0)| ranges the links allow (identifiability.py); each grid point re-evaluates only
    # the part of the links that involves the material (RoomLinks.material_split)
    reflection_ranges: bool = True
    # after the fit, each material the training links cannot tell from a tabulated one (ITU-R P.2040) within one
    # standard error is taken as that one (tabulated.py)
    tabulated_materials: bool = True
    # keep the surfaces crossed from each receiver of the default radio map ([predict.rssi] grid) to the diffuse cells
    # in the model: a map for a new transmitter then traces no receiver (a few MB, a few s of the fit)
    map_visibility: bool = True
    # how a link's paths add up (BANDS); a fitted model stores the one it was fitted with
    band: str = "auto"
    # the terms in dB fitted on the physics' training residuals (rf_fit.residual_choice.parse_request: "auto", "off"
    # or e.g. "field+kriging"; docs/physics.md 8.15)
    residual_terms: str = "auto"
    # parts of large surfaces whose material differs, found where the residuals gather (rf_fit.radio_inset_stage):
    # "auto" searches and keeps them when the held-out training links say so, "off"
    radio_insets: str = "auto"


class RoomGeometry:
    """Patches, diffuse cells and the occlusion provider of a frozen set of surfels."""

    def __init__(self, geom: FrozenGeometry, labels: torch.Tensor | None, material_of_gaussian: np.ndarray,
                 settings: RoomSettings, alpha_min: float = 1e-3, occlusion: str = "auto",
                 areas_m2: torch.Tensor | None = None, extents: dict | None = None,
                 antennas: RoomAntennas | None = None):
        """areas_m2 [G]: the surfels' areas when already known for exactly these Gaussians (a model's stored
        areas, geometry_key matching); None: computed (surfels.surfel_areas). extents: the patches' occupancy
        grids when already known for these Gaussians, labels and settings (room_paths.extent_grids of a model,
        extents_key matching); None: rasterised. antennas: the links' antennas (None: isotropic), which weight
        every path and diffuse cell (links)."""
        self.geom, self.settings, self.alpha_min = geom, settings, float(alpha_min)
        self.antennas = antennas or RoomAntennas()
        self.labels = labels
        self.areas = surfel_areas(geom.means, geom.log_scales, geom.rotations, geom.normals) if areas_m2 is None \
            else torch.as_tensor(areas_m2, dtype=torch.float64)
        self.patches: PatchSet = build_patch_set(geom, self.areas, labels, settings.coplanar_m,
                                                    extent=settings.patch_extent,
                                                    merge_scatter_factor=settings.merge_scatter_factor,
                                                    extents=extents)
        mat = np.asarray(material_of_gaussian, dtype=np.int64)
        # a patch lies within one label, so its surfels share one material: take the first
        first = np.full(self.patches.num, -1)
        first[self.patches.surfel_patch[::-1]] = np.arange(geom.num)[::-1]
        self.material_of_patch = mat[first]
        self.num_materials = int(mat.max()) + 1 if mat.size else 1
        self.cells: DiffuseCells = diffuse_cells(geom.means.numpy(), self.areas.numpy(), self.patches,
                                                 self.material_of_patch, settings.diffuse_cell_m,
                                                 settings.small_patch_share)
        self.provider = make_provider(occlusion, geom, alpha_min)
        # the surfaces crossed from each end to the diffuse cells, kept per point: a map's receivers serve every
        # transmitter
        self.cell_crossings = CellCrossings(self.cells, self.patches, self.provider)

    def geometry_key(self) -> str:
        """Fingerprint of the Gaussians (means, scales, rotations, normals)."""
        return geometry_key(self.geom)

    def extents_key(self) -> str:
        """extents_key of these Gaussians, labels and settings."""
        return extents_key(self.geom, self.labels, self.settings)

    def crossings_key(self) -> str:
        """Fingerprint of what the surfaces crossed from a point to the diffuse cells depend on: the Gaussians,
        the patches (each surfel's patch and each patch's extent), the cells' anchors and the tracer. Stored
        rows are used only where it matches (an edit that moves or deletes Gaussians leaves them unused)."""
        h = hashlib.sha256(self.geometry_key().encode())
        p = self.patches
        for a in (p.surfel_patch, p.grid, p.grid_offset, p.grid_shape, p.grid_origin, p.cell_m, self.cells.anchor):
            h.update(np.ascontiguousarray(a).tobytes())
        h.update(repr((MAX_LEG_CROSSINGS, self.alpha_min, self.provider.name)).encode())
        return h.hexdigest()

    def links(self, tx_m, rx_m, freq_hz, progress=None, axes: LinkAxes | None = None) -> "RoomLinks":
        """Trace the paths and the diffuse weights of links tx_m, rx_m [M, 3] at freq_hz [M]. The antennas'
        patterns enter here, the one place for fitting and prediction alike: each path's amplitude carries
        sqrt(G_tx(departure) G_rx(arrival)) and its end field directions (a dipole's own), each diffuse cell's
        power G_tx toward the cell times G_rx toward it (antenna_patterns.RoomAntennas), each end about its
        link's own axis where `axes` (antenna_patterns.LinkAxes of the M links) has that side's, else its
        EndAntenna's axis."""
        s, ant = self.settings, self.antennas
        axes = axes or LinkAxes()
        axes.check_count(len(tx_m), "the links' antenna axes")
        tx_gain = None if ant.tx.isotropic else ant.tx.gain
        rx_gain = None if ant.rx.isotropic else ant.rx.gain
        tx_field = None if ant.tx.pattern.kind != "dipole" else \
            lambda k, a=None: ant.tx.field_direction(k, s.polarisation, a)
        rx_field = None if ant.rx.pattern.kind != "dipole" else \
            lambda k, a=None: ant.rx.field_direction(k, s.polarisation, a)
        oriented = {"tx_axes": None if ant.tx.isotropic else axes.tx, "rx_axes": None if ant.rx.isotropic else axes.rx}

        def paths() -> RoomPaths:
            return trace_room_paths(tx_m, rx_m, freq_hz, self.patches, self.provider, polarisation=s.polarisation,
                                    max_order=s.max_order, higher_order_min_area_m2=s.higher_order_min_area_m2,
                                    third_order_min_area_m2=s.third_order_min_area_m2,
                                    third_order_small_reflections=s.third_order_small_reflections,
                                    max_interactions=s.max_interactions, tx_gain=tx_gain, rx_gain=rx_gain,
                                    tx_field=tx_field, rx_field=rx_field, **oriented)

        def specular(p: RoomPaths, diffuse: DiffuseTerms | None = None) -> RoomLinks:
            with single_thread_torch():   # small tensor ops: on a shared CPU thread hand-offs cost more than the work
                return RoomLinks(p, diffuse, torch.as_tensor(self.material_of_patch), self.num_materials)

        if not s.diffuse:
            return specular(paths())
        # the paths are traced on a second thread while this one traces the legs to the diffuse cells: they share
        # only the read-only geometry, and most of each runs in numpy or the tracer, outside the GIL (torch's thread
        # count is changed on this thread alone)
        with ThreadPoolExecutor(1) as pool:
            pending = pool.submit(paths)
            diffuse = diffuse_terms(tx_m, rx_m, freq_hz, self.cells, self.material_of_patch, self.num_materials,
                                    self.cell_crossings, tx_gain=tx_gain, rx_gain=rx_gain, **oriented)
            return specular(pending.result(), diffuse)


    def band_links(self, tx_m, rx_m, freq_hz: float, band: str, fitted_hz: float | None = None,
                   axes: LinkAxes | None = None) -> "RoomLinks | BandLinks":
        """The links tx_m, rx_m [M, 3] m (antenna axes `axes`, as links) as `band` (BANDS; "auto" is taken as
        "coherent") sums their paths at freq_hz [Hz], traced once (band_of)."""
        return band_of(self.links(tx_m, rx_m, np.full(len(tx_m), float(freq_hz)), axes=axes), band, freq_hz,
                       fitted_hz)


def band_frequencies(band: str, freq_hz: float, fitted_hz: float | None = None) -> tuple[float, ...]:
    """The frequencies [Hz] whose powers `band` averages at freq_hz: the three BLE advertising channels for "ble"
    (shifted by freq_hz - fitted_hz, the model's own frequency, when a model fitted at fitted_hz is evaluated
    elsewhere: the channels keep their spacing about the frequency asked), else freq_hz alone."""
    if band != "ble":
        return (float(freq_hz),)
    shift = 0.0 if fitted_hz is None else float(freq_hz) - float(fitted_hz)
    return tuple(f + shift for f in BLE_CHANNELS_HZ)


def band_of(links: "RoomLinks", band: str, freq_hz: float, fitted_hz: float | None = None) -> "RoomLinks | BandLinks":
    """Traced links as `band` (BANDS; "auto" is taken as "coherent") sums their paths at freq_hz [Hz]: the same
    paths and diffuse terms evaluated at band_frequencies (a BandLinks of the three BLE channels; RoomLinks with
    incoherent set for "incoherent"); nothing is traced again."""
    if band == "ble":
        return BandLinks([links.at_frequency(f) for f in band_frequencies(band, freq_hz, fitted_hz)])
    # links already at freq_hz are taken as they are (a shallow copy: their tables are not built again)
    same = bool((links.paths.freq_hz == float(freq_hz)).all())
    out = copy.copy(links) if same else links.at_frequency(float(freq_hz))
    out.incoherent = band == "incoherent"
    return out


def extents_key(geom: FrozenGeometry, labels: torch.Tensor | None, settings: RoomSettings) -> str:
    """Fingerprint of what the patches' occupancy grids depend on: the Gaussians, their labels [G], the patch
    settings and the rasterisation's constants. A model's stored grids are used only where it matches."""
    h = hashlib.sha256(geometry_key(geom).encode())
    if labels is not None:
        h.update(np.ascontiguousarray(labels.numpy(), dtype=np.int64).tobytes())
    h.update(repr((settings.coplanar_m, settings.patch_extent, settings.merge_scatter_factor, FOOTPRINT_REACH,
                   TILE_CLOSING, CELL_PER_TILE)).encode())
    return h.hexdigest()


def geometry_key(geom: FrozenGeometry) -> str:
    """sha256 of the Gaussians' means, log-scales, rotations and normals (what a surfel's area depends on)."""
    h = hashlib.sha256()
    for t in (geom.means, geom.log_scales, geom.rotations, geom.normals):
        h.update(np.ascontiguousarray(t.detach().numpy(), dtype=np.float64).tobytes())
    return h.hexdigest()


ANGLE_NODES = 91   # Fresnel coefficients tabulated at 1-degree steps of the incidence angle, linear between


def coefficient_tables(freqs: torch.Tensor, mats: MaterialValues, only: int | None = None) -> torch.Tensor:
    """[4 * N * F * ANGLE_NODES] complex, blocks R_TE, R_TM, T_TE, T_TM of every material, frequency freqs [F] Hz
    and angle node (only: of that material alone, [4 * F * ANGLE_NODES])."""
    pick = slice(None) if only is None else slice(only, only + 1)
    cos = AngleNodes(ANGLE_NODES).cosines()
    eta = mats.eta(freqs)[pick, :, None]                                            # [N, F, 1]
    k0 = (2 * math.pi * freqs / C0)[None, :, None]
    th = None if mats.thickness_m is None else mats.thickness_m[pick, None, None]
    r_te, r_tm = fresnel(eta, cos, k0, th)
    if th is None:
        t_te = t_tm = torch.zeros_like(r_te)
    else:
        t_te, t_tm = slab_transmission(eta, cos, k0, th)
    return torch.stack([r_te, r_tm, t_te, t_tm]).reshape(-1)


def _distinct_rows(rows: torch.Tensor, base: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(distinct rows [U, I], index [Q] of each row's) of rows [Q, I] int64 in 0..base-1: packed into one int64 key
    where base^I fits (a 1-D unique, twenty times faster than unique over rows), else unique over rows."""
    q, width = rows.shape
    if width == 0 or q == 0 or width * math.log2(max(base, 2)) >= 62:
        return torch.unique(rows, dim=0, return_inverse=True)
    key = torch.zeros(q, dtype=torch.int64)
    for c in range(width):
        key = key * base + rows[:, c]
    keys, inverse = torch.unique(key, return_inverse=True)
    first = torch.empty(len(keys), dtype=torch.int64).scatter_(0, inverse, torch.arange(q))
    return rows[first], inverse


class DiffuseMatrix:
    """DiffuseTerms.power of links at one frequency as matrix products, for links evaluated many times (a fit's
    steps; equal to rounding, tested). With R = N x NODES the materials' |Gamma|^2 S^2 nodes g2 [R] and the
    products of |T|^2 over each combination of surfaces crossed, through [U] (ObstructedCells.crossings),

        P_diff = (W + A through) g2,

    W [M, R] the unobstructed weights and A [M R, U] sparse (CSR) the obstructed terms' weights at row
    link x R + refl, column combo, lambda^2 in both. A step then touches each obstructed term twice (A through,
    and A^T times the gradient on the way back) where the gathers, products and scatters of DiffuseTerms.power
    touch it a dozen times: twice as fast a fit step on the rooms of measured surveys, where each link has a
    thousand such terms. Memory: A and A^T, 32 bytes a term (DiffuseTerms holds 32)."""

    def __init__(self, diffuse: DiffuseTerms):
        ob, m = diffuse.obstructed, diffuse.num_links
        self.freq_hz, self.crossings = diffuse.freq_hz, ob.crossings
        lam2 = diffuse.lambda2()
        self.shape = (m, int(diffuse.weight.shape[1]) * int(diffuse.weight.shape[2]))
        self.unobstructed = (diffuse.weight * lam2[:, None, None]).reshape(self.shape)
        rows, cols = ob.link * self.shape[1] + ob.refl, ob.combo
        vals = ob.weight * lam2[ob.link]
        u = int(ob.crossings.shape[0])
        self.matrix = _csr(rows, cols, vals, (m * self.shape[1], u))
        self.transposed = _csr(cols, rows, vals, (u, m * self.shape[1]))

    def power(self, eta_of_material: torch.Tensor, thickness_m: torch.Tensor | None,
              scattering: torch.Tensor) -> torch.Tensor:
        """P_diff [M] W (P_T = 1 W) for materials' eta [N, 1] (the one frequency), thickness [N] m, S [N]."""
        g2 = diffuse_reflectance(eta_of_material, thickness_m, scattering, self.freq_hz).reshape(-1)
        weight = self.unobstructed
        if self.matrix.values().numel():
            t2 = diffuse_transmittance(eta_of_material, thickness_m, self.freq_hz)
            t2 = torch.cat([t2, torch.ones_like(t2[:1])]).reshape(-1)          # the row of "no crossing"
            through = t2.index_select(0, self.crossings.reshape(-1)).view(self.crossings.shape).prod(1)
            weight = weight + _SparseProduct.apply(through, self.matrix, self.transposed).view(self.shape)
        return weight @ g2


def _csr(rows: torch.Tensor, cols: torch.Tensor, vals: torch.Tensor, shape: tuple) -> torch.Tensor:
    """Sparse CSR [shape] float64 of entries (rows, cols, vals) [K] (summed where repeated)."""
    order = torch.argsort(rows * shape[1] + cols)
    crow = torch.zeros(shape[0] + 1, dtype=torch.int64)
    crow[1:] = torch.cumsum(torch.bincount(rows, minlength=shape[0]), 0)
    with warnings.catch_warnings():   # torch calls its CSR support beta; products and their gradients are tested here
        warnings.simplefilter("ignore", UserWarning)
        return torch.sparse_csr_tensor(crow, cols[order], vals[order].to(torch.float64), shape)


class _SparseProduct(torch.autograd.Function):
    """A x for a sparse A [R, U] (CSR) with its transpose given (A^T g is the gradient of x)."""

    @staticmethod
    def forward(ctx, x, matrix, transposed):
        ctx.transposed = transposed
        return (matrix @ x[:, None])[:, 0]

    @staticmethod
    def backward(ctx, grad):
        return (ctx.transposed @ grad[:, None])[:, 0], None, None


class RoomLinks:
    """Traced paths and diffuse weights of M links; material_of_patch [P] int64.

    A fit step evaluates each material's coefficients on ANGLE_NODES incidence angles per distinct
    frequency and interpolates them per interaction (the exact evaluation is RoomPaths.field; they agree
    within 0.01 dB, tested)."""

    def __init__(self, paths: RoomPaths, diffuse: DiffuseTerms | None, material_of_patch: torch.Tensor,
                 num_materials: int, incoherent: bool = False):
        # incoherent: the paths add in power (band "incoherent"); the field is then not linear in one
        # interaction's coefficients, so material_part (which relies on it) refuses such links
        self.incoherent = bool(incoherent)
        self.paths, self.diffuse = paths, diffuse
        self.material_of_patch, self.num_materials = material_of_patch, int(num_materials)
        self.freqs, fid = torch.unique(paths.freq_hz, return_inverse=True)
        mat = material_of_patch[paths.patch]                                           # [Q, I]
        j, frac = AngleNodes(ANGLE_NODES).position(paths.cos)
        frac = frac.to(torch.complex128)
        index = (mat * len(self.freqs) + fid[paths.link][:, None]) * ANGLE_NODES + j
        refl = paths.kind == 1
        # per used slot: the entries of the flat table (_tables: R_TE, R_TM, T_TE, T_TM blocks) at the angle nodes
        # below and above each interaction's angle, TE then TM, as one index [4 n] (a step gathers them with one
        # index_select, several times faster than four gathers by advanced indexing, backward included), and the
        # interpolation weight
        block = num_materials * len(self.freqs) * ANGLE_NODES
        self._slots = []
        for i, n in enumerate(paths.slot_use()):
            if n == 0:
                continue
            te = index[:n, i] + torch.where(refl[:n, i], 0, 2 * block)
            self._slots.append((torch.cat([te, te + 1, te + block, te + block + 1]), frac[:n, i].contiguous()))
        # materials of each path's reflections (num_materials: none), for the specular share: the paths share a few
        # distinct rows (refl_rows [U, I]; refl_row_of_path [Q]), whose products a step takes once each
        self._refl_rows, self._refl_row_of_path = _distinct_rows(torch.where(refl, mat, torch.full_like(mat, num_materials)),
                                                                 num_materials + 1)
        # the diffuse power as matrix products (DiffuseMatrix), built at the second evaluation: a fit evaluates the
        # same links hundreds of times, a prediction once
        self._diffuse_matrix, self._evaluations = None, 0

    @property
    def num_links(self) -> int:
        return self.paths.num_links

    def select_paths(self, keep: torch.Tensor) -> "RoomLinks":
        """The same links with the specular paths where keep [Q] bool is true (the diffuse terms unchanged)."""
        out = RoomLinks(self.paths.select_paths(keep), self.diffuse, self.material_of_patch, self.num_materials,
                        self.incoherent)
        out._diffuse_matrix = self._diffuse_matrix     # the same diffuse terms
        return out

    def select_links(self, rows) -> "RoomLinks":
        return RoomLinks(self.paths.select_links(rows), None if self.diffuse is None else self.diffuse.select_links(rows),
                         self.material_of_patch, self.num_materials, self.incoherent)

    def at_frequency(self, freq_hz) -> "RoomLinks":
        """The same traced links evaluated at freq_hz (a number [Hz] for every link, or [M] one per link):
        RoomPaths.at_frequency and DiffuseTerms.at_frequency, nothing traced again."""
        return RoomLinks(self.paths.at_frequency(freq_hz),
                         None if self.diffuse is None else self.diffuse.at_frequency(freq_hz),
                         self.material_of_patch, self.num_materials, self.incoherent)

    def material_split(self, i: int) -> tuple[torch.Tensor, "RoomLinks", "RoomLinks"]:
        """(rows [M_i] int64, without, with): the links whose field or diffuse power depends on material i, and
        those links' specular paths and diffuse terms that do not involve it (without) and that do (with: a path
        that reflects off or crosses a patch of it, a term of its cells or through its slabs). The field and the
        diffuse power of the rows are the sums of the two parts' components, so a change of material i alone
        needs the second part only (the ranges of rfir_stages.model.identifiability); the other links keep
        their power."""
        touch = ((self.paths.kind > 0) & (self.material_of_patch[self.paths.patch] == i)).any(1)    # [Q]
        depends = torch.zeros(self.num_links, dtype=torch.bool)
        depends[self.paths.link[touch]] = True
        diffuse = (None, None)
        if self.diffuse is not None:
            on, without, with_i = self.diffuse.split_material(i)
            depends |= on
        rows = torch.nonzero(depends).reshape(-1)
        if self.diffuse is not None:
            diffuse = without.select_links(rows), with_i.select_links(rows)
        paths = self.paths.select_links(rows)
        touch = ((paths.kind > 0) & (self.material_of_patch[paths.patch] == i)).any(1)
        return (rows, RoomLinks(paths.select_paths(~touch), diffuse[0], self.material_of_patch, self.num_materials),
                RoomLinks(paths.select_paths(touch), diffuse[1], self.material_of_patch, self.num_materials))

    def _tables(self, mats: MaterialValues, only: int | None = None) -> torch.Tensor:
        """coefficient_tables at these links' frequencies."""
        return coefficient_tables(self.freqs, mats, only)

    def components(self, mats: MaterialValues, tables: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(specular field [M] complex, diffuse power [M] W); tables: _tables(mats) where the caller has them.
        Incoherent links: the field is 0 and the specular paths' powers sum_p |a_p|^2 are in the second term."""
        if int(mats.eps_r.numel()) != self.num_materials:
            # the tables' blocks are laid out per material: another count would read other materials' coefficients
            raise ValueError(f"{int(mats.eps_r.numel())} materials given for links of {self.num_materials}")
        tab = self._tables(mats) if tables is None else tables
        coefficients = []
        for at, frac in self._slots:
            lo_te, hi_te, lo_tm, hi_tm = tab.index_select(0, at).view(4, -1)
            coefficients.append((lo_te + (hi_te - lo_te) * frac, lo_tm + (hi_tm - lo_tm) * frac))
        spec_m = specular_share(mats.scattering)
        spec = torch.cat([spec_m, torch.ones(1, dtype=torch.float64)])[self._refl_rows].prod(1).index_select(
            0, self._refl_row_of_path)
        field = self.paths.chain(coefficients, spec, self.incoherent)
        if self.incoherent:
            field, power = torch.zeros(self.num_links, dtype=torch.complex128), field
        else:
            power = torch.zeros(self.num_links, dtype=torch.float64)
        if self.diffuse is None:
            return field, power
        f = self.paths.freq_hz
        if len(f) == 0:       # no link (a material no link depends on, RoomLinks.material_split)
            return field, power
        one_freq = bool((f == f[0]).all())
        eta = mats.eta(f[:1]) if one_freq else mats.eta(f)
        self._evaluations += 1
        if one_freq and self._diffuse_matrix is None and self._evaluations > 1:
            self._diffuse_matrix = DiffuseMatrix(self.diffuse)
        if one_freq and self._diffuse_matrix is not None:
            return field, power + self._diffuse_matrix.power(eta, mats.thickness_m, mats.scattering)
        return field, power + self.diffuse.power(eta, mats.thickness_m, mats.scattering)

    def material_part(self, i: int, mats: MaterialValues) -> "MaterialPart":
        """The links' power as material i alone changes from mats (MaterialPart)."""
        if self.incoherent:
            raise ValueError("material_part needs the coherent field (linear in each interaction's coefficients)")
        return MaterialPart(self, i, mats)

    def power(self, mats: MaterialValues, gain_db: torch.Tensor | float = 0.0) -> torch.Tensor:
        """Received power [M, 1] W (P_T = 1 W): g (|field|^2 + P_diff)."""
        field, diff = self.components(mats)
        g = 10 ** (torch.as_tensor(gain_db, dtype=torch.float64) / 10)
        return (g * (abs2(field) + diff))[:, None]


class BandLinks:
    """M links evaluated at each of C channel frequencies (C RoomLinks of one trace, RoomLinks.at_frequency: the
    traced geometry does not depend on the frequency); the power is the mean over the channels of each channel's
    coherent power,
    what an RSSI averaged over the channels measures. Has the interface the fit uses (power, num_links, paths,
    select_links, select_paths); no material_part, so the |Gamma| ranges evaluate every link."""

    def __init__(self, parts: list):
        if len({p.paths.num for p in parts}) != 1:
            raise ValueError("the channels' links must have the same paths")
        self.parts = parts

    @property
    def num_links(self) -> int:
        return self.parts[0].num_links

    @property
    def paths(self) -> RoomPaths:
        """The first channel's paths (the others' differ in frequency alone)."""
        return self.parts[0].paths

    def select_links(self, rows) -> "BandLinks":
        return BandLinks([p.select_links(rows) for p in self.parts])

    def select_paths(self, keep: torch.Tensor) -> "BandLinks":
        """keep [Q] bool, of the shared paths."""
        return BandLinks([p.select_paths(keep) for p in self.parts])

    def power(self, mats: MaterialValues, gain_db: torch.Tensor | float = 0.0) -> torch.Tensor:
        """Received power [M, 1] W (P_T = 1 W): the mean over channels of RoomLinks.power."""
        return torch.stack([p.power(mats, gain_db) for p in self.parts]).mean(0)


# the diffuse nodes on the specular tables' angle nodes: |Gamma|^2 on every DIFFUSE_STEP-th, |T|^2 on each
DIFFUSE_STEP = (ANGLE_NODES - 1) // (DIFFUSE_NODES - 1)
NODES_ALIGNED = DIFFUSE_STEP * (DIFFUSE_NODES - 1) == ANGLE_NODES - 1 and CROSSING_NODES == ANGLE_NODES


class MaterialPart:
    """The power of the links that depend on material i (rows [M_i] int64 of RoomLinks.material_split) as a
    function of that material alone, every other held at the values it was built with. Evaluated once: the
    field of the paths that do not involve material i and the diffuse terms without it. A path that meets
    material i once has a field linear in that interaction's TE and TM coefficients (the polarisation chain is
    a product of per-interaction maps), so it is kept as two fixed amplitudes, and a call interpolates the two
    coefficients; the paths that meet it more often are evaluated whole (RoomLinks.components with material
    i's block of the coefficient tables recomputed alone). Material i's diffuse terms are fixed factors times
    its own |Gamma|^2 S^2 and |T|^2 (DiffuseTerms.material_form; one frequency, else evaluated whole). The
    diffuse nodes are angle nodes of the specular tables (NODES_ALIGNED), so one evaluation of material i's
    Fresnel coefficients serves both. Equal to RoomLinks.power to rounding."""

    def __init__(self, links: RoomLinks, i: int, mats: MaterialValues):
        self.material = int(i)
        self.rows, without, with_i = links.material_split(i)
        self.field0, self.diff0 = without.components(mats)
        p, n = with_i.paths, links.num_materials
        self.freqs = torch.unique(p.freq_hz)                       # [F] Hz: material i's own tables at these
        mine = (p.kind > 0) & (links.material_of_patch[p.patch] == i)                       # [Q_i, I]
        once = mine.sum(1) == 1
        self.several = RoomLinks(p.select_paths(~once), None, links.material_of_patch, n)
        self.tables = self.several._tables(mats).reshape(4, n, len(self.several.freqs) * ANGLE_NODES)
        # the paths that meet material i once: amplitudes [Q1] with its coefficients (TE, TM) = (1, 0) and (0, 1),
        # its specular share sqrt(1 - S^2) left out (S = 0), each path its own "link"
        one = p.select_paths(once)
        q = one.num
        alone = RoomLinks(RoomPaths(q, torch.arange(q), one.length_m, one.gain, one.order, one.e_tx, one.e_rx, one.kind,
                                    one.patch, one.cos, one.s, one.p_in, one.p_out, one.freq_hz[one.link]),
                          None, links.material_of_patch, n)
        plain = MaterialValues(mats.eps_r, mats.sigma_1ghz, mats.sigma_exponent,
                               torch.where(torch.arange(n) == i, 0.0, mats.scattering), mats.thickness_m)
        unit, fixed = [], alone._tables(mats).reshape(4, n, len(alone.freqs) * ANGLE_NODES)
        for te in (1.0, 0.0):
            t = fixed.clone()
            t[:, i] = torch.tensor([te, 1.0 - te, te, 1.0 - te], dtype=torch.complex128)[:, None]
            unit.append(alone.components(plain, t.reshape(-1))[0])
        self.unit_te, self.unit_tm = unit
        self.link_once = one.link
        # where each such path reads material i's table [4 * width]: as RoomLinks.__init__ does, for one material
        slot = mine[once].to(torch.int8).argmax(1)
        at = torch.arange(q)
        j, frac = AngleNodes(ANGLE_NODES).position(one.cos[at, slot])
        self.frac = frac.to(torch.complex128)
        self.reflects = one.kind[at, slot] == 1
        fid = torch.searchsorted(self.freqs, one.freq_hz[one.link])
        self.te_at = torch.where(self.reflects, 0, 2) * len(self.freqs) * ANGLE_NODES + fid * ANGLE_NODES + j
        self.diffuse, self.form = with_i.diffuse, None
        f = p.freq_hz
        if self.diffuse is not None and len(f) and bool((f == f[0]).all()) and NODES_ALIGNED:
            self.form = self.diffuse.material_form(i, mats.eta(f[:1]), mats.thickness_m, mats.scattering)

    def power(self, mats: MaterialValues, gain_db: torch.Tensor | float = 0.0) -> torch.Tensor:
        """Received power [M_i] W (P_T = 1 W) of the rows: g (|field|^2 + P_diff); mats differ from those the
        part was built with in material i alone."""
        i = self.material
        own = coefficient_tables(self.freqs, mats, only=i).reshape(4, -1)   # R_TE, R_TM, T_TE, T_TM on the nodes
        tables = self.tables.clone()
        tables[:, i] = own           # select_paths keeps every link, so `several` has the rows' frequencies
        field = self.field0 + self.several.components(mats, tables.reshape(-1))[0]
        flat, te, frac = own.reshape(-1), self.te_at, self.frac
        width = own.shape[1]
        c_te = flat[te] + (flat[te + 1] - flat[te]) * frac
        c_tm = flat[te + width] + (flat[te + width + 1] - flat[te + width]) * frac
        share = torch.where(self.reflects, specular_share(mats.scattering[i]), 1.0)
        field = field.index_add(0, self.link_once, (self.unit_te * c_te + self.unit_tm * c_tm) * share)
        diff = self.diff0
        if self.form is not None:
            g2 = 0.5 * (abs2(own[0]) + abs2(own[1]))[::DIFFUSE_STEP] * mats.scattering[i] ** 2
            diff = diff + self.form.power(g2, 0.5 * (abs2(own[2]) + abs2(own[3])))
        elif self.diffuse is not None:
            diff = diff + self.diffuse.power(mats.eta(self.diffuse.freq_hz), mats.thickness_m, mats.scattering)
        g = 10 ** (torch.as_tensor(gain_db, dtype=torch.float64) / 10)
        return g * (abs2(field) + diff)


class RoomPredictor:
    """A fitted physical room model (rf artifact written by rf_fit.room_stage), ready to predict.

    Used by predict rssi, edit and diagnose (predict.rssi_model_io.load_predictor): geom, provider, freq_hz (the
    frequency it was fitted at), path_gain_db, predict_db (at any frequency inside frequency_range_hz: the traced
    paths hold no wavelength), memory_estimate_bytes."""

    BYTES_PER_LINK = 40_000   # paths x interaction slots x (basis vectors + coefficients), measured on rooms

    def __init__(self, rf, occlusion: str = "auto"):
        from dataclasses import fields as dc_fields



        attrs = rf.free.get("model@attrs", {})
        model = load_physical(rf)
        self.mats, self.gain_db = model.mats, model.gain_db
        stored = rf.free.get("model", {})
        self.device_gains = {k: np.asarray(v) for k, v in stored.items() if k.startswith("device_")}
        self.device_ends_matched = 0    # link ends of the last path_gain_db call that got a fitted device gain
        # each material's tabulated key where the fit took a tabulated one ("": as fitted; frequency_range_hz)
        self.tabulated = [str(k) for k in np.atleast_1d(attrs.get("material_tabulated", []))]
        kw = {}
        for f in dc_fields(RoomSettings):
            if f"room.{f.name}" in attrs:
                kw[f.name] = type(getattr(RoomSettings, f.name))(attrs[f"room.{f.name}"])
        # models that store no extent were fitted when every patch was made of disks
        kw.setdefault("patch_extent", "disks")
        # and those that store no merge factor, when patches were joined neighbour by neighbour only
        kw.setdefault("merge_scatter_factor", 0.0)
        # and a cell per patch, when they store no pooling share
        kw.setdefault("small_patch_share", 0.0)
        # and their third order off large patches alone, when they store no small reflections
        kw.setdefault("third_order_small_reflections", 0)
        # and coherent sums at one frequency, when they store no band
        kw.setdefault("band", "coherent")
        self.geom = geometry_from_artifact(rf)
        labels = rf.get("gaussians/labels")
        self.freq_hz = float(np.asarray(rf["rf/freq_hz"])[0])
        # the fit's surfel areas, while the Gaussians are the fitted ones (an edit that moves or deletes some
        # changes the areas of their neighbours: then they are computed again)
        same = attrs.get("geometry_key") == geometry_key(self.geom)
        settings = RoomSettings(**kw)
        label_tensor = None if labels is None else torch.as_tensor(np.asarray(labels, np.int64))
        # the fit's patch grids, while the Gaussians, labels and patch settings are the fitted ones
        grids = {k[len("patch_"):]: stored[k] for k in stored if k.startswith("patch_")}
        key = extents_key(self.geom, label_tensor, settings) if grids else None
        self.room = RoomGeometry(self.geom, label_tensor, model.material_of_gaussian.numpy(), settings,
                                 float(attrs.get("render.alpha_min", 1e-3)), occlusion,
                                 areas_m2=model.areas_m2 if same else None,
                                 extents=grids if key and attrs.get("patch_extents_key") == key else None,
                                 antennas=RoomAntennas.from_attrs(attrs))
        self.provider = self.room.provider
        if attrs.get("map_crossings_key") == self.room.crossings_key() and "map_rx_m" in stored:
            self.room.cell_crossings.keep(np.asarray(stored["map_rx_m"]), np.asarray(stored["map_cell_crossings"]))

    def memory_estimate_bytes(self, num_links: int, chunk_links: int) -> int:
        return int(min(num_links, chunk_links) * self.BYTES_PER_LINK + num_links * 200)

    def frequency_range_hz(self) -> tuple[float, float, str]:
        """(lowest, highest [Hz], why): the frequencies the model's material laws hold at. A fitted material follows
        the ITU-R P.2040 form (eps_r constant, sigma = sigma_1GHz (f / 1 GHz)^d), stated for FITTED_LAW_RANGE_GHZ;
        a material taken as a tabulated one (rf_fit.room.tabulated_materials) holds over that law's own range."""

        lo, hi = FITTED_LAW_RANGE_GHZ
        why = f"the fitted ITU-R P.2040 law's {lo:g}-{hi:g} GHz"
        for key in sorted({str(k) for k in self.tabulated if str(k)}):
            f_lo, f_hi = ITU_MATERIALS[key][4:6] if key in ITU_MATERIALS else (lo, hi)
            if f_lo > lo or f_hi < hi:
                lo, hi = max(lo, f_lo), min(hi, f_hi)
                why = f"{key}'s ITU-R P.2040 law: {f_lo:g}-{f_hi:g} GHz"
        return lo * 1e9, hi * 1e9, why

    def check_frequencies(self, freqs_hz) -> np.ndarray:
        """freqs_hz as [F] float64 Hz; a ConfigError (one line) for one outside frequency_range_hz."""

        f = np.atleast_1d(np.asarray(freqs_hz, dtype=np.float64))
        lo, hi, why = self.frequency_range_hz()
        bad = f[~(np.isfinite(f) & (f >= lo) & (f <= hi))]
        if f.size == 0 or bad.size:
            shown = "none" if f.size == 0 else f"{bad[0] / 1e9:g} GHz"
            raise ConfigError(f"frequency {shown} is outside {lo / 1e9:g}-{hi / 1e9:g} GHz, where this model's "
                              f"material laws hold ({why})")
        return f

    def path_gain_db(self, tx_m: np.ndarray, rx_m: np.ndarray, chunk_links: int = 512, progress=None,
                     axes: LinkAxes | None = None) -> np.ndarray:
        """Predicted path gain [N] dB for links tx_m / rx_m [N, 3] m at the frequency the model was fitted at
        (predict_db at freq_hz)."""
        return self.predict_db(tx_m, rx_m, [self.freq_hz], chunk_links, progress, axes)[:, 0]

    def predict_db(self, tx_m: np.ndarray, rx_m: np.ndarray, freqs_hz=None, chunk_links: int = 512,
                   progress=None, axes: LinkAxes | None = None) -> np.ndarray:
        """Predicted path gain [N, F] dB for links tx_m / rx_m [N, 3] m at freqs_hz [F] Hz (None: the frequency the
        model was fitted at, freq_hz; each inside frequency_range_hz, else a ConfigError), floored at -250 dB: the
        paths summed as the model's band (RoomSettings.band; "ble" averages the three advertising channels, moved
        with the frequency asked, band_frequencies), with the fitted gain of each device the fit saw at that
        position (device_gains.gains_at), the antennas about each link's axis where `axes` (LinkAxes [N]) has
        its side's (RoomGeometry.links). Each block of chunk_links links is traced once, every frequency evaluated
        on that trace."""

        freqs = np.asarray([self.freq_hz]) if freqs_hz is None else self.check_frequencies(freqs_hz)
        tx_m, rx_m = np.asarray(tx_m, np.float64), np.asarray(rx_m, np.float64)
        device_db, self.device_ends_matched = gains_at(self.device_gains, tx_m, rx_m)
        out = np.empty((len(tx_m), len(freqs)))
        with torch.no_grad():
            for lo in range(0, len(tx_m), chunk_links):
                hi = min(len(tx_m), lo + chunk_links)
                traced = self.room.links(tx_m[lo:hi], rx_m[lo:hi], np.full(hi - lo, self.freq_hz),
                                         axes=None if axes is None else axes.rows(slice(lo, hi)))
                for j, f in enumerate(freqs):
                    # the sum the model was fitted with (room.band), so predict, edit and diagnose agree with the fit
                    links = band_of(traced, self.room.settings.band, float(f), self.freq_hz)
                    with single_thread_torch():   # ten times faster than two threads on a busy CPU
                        p = links.power(self.mats, self.gain_db)[:, 0].numpy()
                    out[lo:hi, j] = np.maximum(10 * np.log10(np.maximum(p, 1e-300)) + device_db[lo:hi], FLOOR_DB)
                if progress is not None:
                    progress.advance(hi - lo)
        return out
