"""The physical forward model: surfel physical optics with physical materials (docs/physics.md section 8).

Received complex amplitude and power for a batch of links (P_T = 1 W, path gain = power):

    S_spec = sum_l j sqrt(G_T G_R) sqrt(1 - S_m^2) Gamma_m(theta_l, pol) A_l ((cos_i + cos_o) / 2)
             * F_l(k) * V_l * exp(-j k (d_i + d_o)) / (4 pi d_i d_o)
    P_diff = sum_l G_T G_R S_m^2 |Gamma_m(theta_l)|^2 A_l cos_i cos_o lambda^2 V_l^2 / (16 pi^3 d_i^2 d_o^2)
    P      = g (|S_spec|^2 + P_diff)

- l runs over surfel Gaussians lit from both ends (the normal flipped to face the transmitter,
  cos_i = n.w_i > 0 and cos_o = n.w_o > 0: the receiver on the same side; no transmission here);
  m = material of l (one per label, per segment or per scene);
- A_l: surfel area (surfels.surfel_areas), so a plate at broadside gives 4 pi A^2 / lambda^2
  whatever the Gaussian density; F_l(k) = sinc(k q.c_1) sinc(k q.c_2), q = w_i + w_o, the
  footprint factor of the surfel's cell (surfels.footprint_cells);
- Gamma_m(theta, pol): the co-polarised Fresnel (slab) coefficient of the material at the local
  incidence angle (materials.co_polar_reflection; the TE share from the antennas' polarisation);
- V_l = V_tx V_rx: the lit/shadowed state (1 or 0) of the surfel's mean from each antenna: lit when
  the transmittance traced through the Gaussians (one RF opacity for every Gaussian, frozen) exceeds
  `lit_threshold` (traced_lit), as physical optics lights a facet (surfaces are opaque; docs/physics.md
  section 8.6); one factor when the antennas are co-located, which is the monostatic radar (the two
  legs share one path);
- g: a system gain (1 unless fitted: the level is physical);
- with settings.edge_waves, the fringe field of the planar patches' outer edges is added to S_spec
  (edges.py, docs/physics.md section 8.13), as the double and triple bounces are (second_order.py,
  third_order.py).
The phase of each term is fixed by geometry and the material: no free phase per Gaussian.

Everything that depends on geometry alone is computed once (`build_pairs`); `PhysicalModel.power`
is then O(pairs x frequencies) and differentiable in the material parameters.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from rfir_core.physics.angle_nodes import AngleNodes
from rfir_core.physics.materials import (C0, METAL_SIGMA_S_PER_M, abs2, co_polar_reflection, fresnel, law_permittivity,
                                         specular_share)
from rfir_core.physics.polarisation import te_share
from rfir_core.threads import single_thread_torch

from .antenna_patterns import AntennaPattern
from .occlusion import FrozenGeometry, OcclusionProvider, lit_stop
from .link_set import LinkSet
from .link_rows import renumber_links
from .edges import EdgeTerms, aggregate_edges, edge_field, edge_reflection, edge_terms, patch_edges
from .second_order import DoubleBounce, Patches, build_double_bounce, planar_patches
from .third_order import TripleBounce, build_triple_bounce
from .surfels import covariance, footprint_cells, footprint_factor, surfel_areas

EPS_R_MAX = 25.0            # relative permittivity in [1, EPS_R_MAX]
LOG10_SIGMA = (-4.0, math.log10(METAL_SIGMA_S_PER_M))   # conductivity at 1 GHz in [1e-4 S/m, a metal's]
THICKNESS_M = (1e-3, 1.0)   # slab thickness range, m
DENSE_VIS_MAX = 1 << 24     # links x Gaussians up to which the visibility lookup is a dense table (128 MiB)


@dataclass
class PairGeometry:
    """Geometry of every (link, lit surfel) pair; P pairs, M links, K frequencies.

    link, gauss [P] int64; d_i, d_o [P] m; cos_i, cos_o [P]; te_share [P] in [0, 1]; gain [P] =
    sqrt(G_T G_R); vis [P] = V_tx V_rx; q_cell [P, 2] m = C_l q (surfels.footprint_cells); area [P] m^2;
    freq_hz [K]."""

    num_links: int
    link: torch.Tensor
    gauss: torch.Tensor
    d_i: torch.Tensor
    d_o: torch.Tensor
    cos_i: torch.Tensor
    cos_o: torch.Tensor
    te_share: torch.Tensor
    gain: torch.Tensor
    vis: torch.Tensor
    q_cell: torch.Tensor
    area: torch.Tensor
    freq_hz: torch.Tensor
    double: "DoubleBounce | None" = None    # second-order items (second_order.py), None: first order only
    edges: "EdgeTerms | None" = None        # edge-wave items (edges.py), None: no edge waves
    triple: "TripleBounce | None" = None    # third-order items (third_order.py; no frequency: any columns), None: none

    @property
    def num_pairs(self) -> int:
        return int(self.link.numel())

    def visibility_of(self, link: torch.Tensor, gauss: torch.Tensor, num_gaussians: int) -> torch.Tensor:
        """V of the (link, surfel) pairs asked for (index tensors of broadcastable shapes); 0 for pairs
        that are not lit (not in the table).

        Looked up many times per build (the double bounces): a dense [M, G] table when it holds at most
        DENSE_VIS_MAX entries, else a sorted key and a binary search."""
        cached = self.__dict__.get("_vis_index")
        if cached is None or cached[0] != num_gaussians:     # built once, looked up many times
            key = self.link * num_gaussians + self.gauss
            if self.num_links * num_gaussians <= DENSE_VIS_MAX:
                table = torch.zeros(self.num_links * num_gaussians, dtype=torch.float64)
                table[key] = self.vis.double()
                cached = (num_gaussians, table.reshape(self.num_links, num_gaussians), None)
            else:
                order = torch.argsort(key)
                cached = (num_gaussians, key[order], self.vis[order])
            self.__dict__["_vis_index"] = cached
        _, sk, sv = cached
        if sv is None:
            return sk[link, gauss]
        want = link * num_gaussians + gauss
        if sk.numel() == 0:
            return torch.zeros(want.shape, dtype=torch.float64)
        pos = torch.searchsorted(sk, want).clamp(max=sk.numel() - 1)
        return torch.where(sk[pos] == want, sv[pos], torch.zeros((), dtype=torch.float64))

    def select_links(self, rows) -> "PairGeometry":
        """The pairs of links `rows` (renumbered 0..len(rows)-1 in that order)."""
        rows, keep, new_link = renumber_links(self.link, self.num_links, rows)
        pick = lambda t: t[keep]  # noqa: E731
        return PairGeometry(int(rows.numel()), new_link, pick(self.gauss), pick(self.d_i),
                            pick(self.d_o), pick(self.cos_i), pick(self.cos_o), pick(self.te_share), pick(self.gain),
                            pick(self.vis), pick(self.q_cell), pick(self.area), self.freq_hz,
                            None if self.double is None else self.double.select_links(rows),
                            None if self.edges is None else self.edges.select_links(rows),
                            None if self.triple is None else self.triple.select_links(rows))


@dataclass
class PairSettings:
    """visibility: trace V (False: every lit surfel sees both antennas). opacity: the RF opacity of
    every Gaussian for the traced V. margin_m: occluders closer than this in front of a surfel are
    ignored (a surface does not shadow itself). colocated_tol_m: Tx and Rx closer than this are one
    radar (one visibility factor). polarisation: "V" or "H". link_chunk: links per geometry block.
    second_order: add double bounces between planar patches of at least min_patch_area_m2 (second_order.py),
    and with third_order triple bounces at their corners (third_order.py); co-located antennas only.
    lit_threshold: a surfel is lit from an antenna when
    the traced transmittance exceeds this (V = 1, else 0: opaque surfaces with sharp shadow edges);
    0: V is the transmittance itself (soft shadows). edge_waves: add the fringe field of the patches'
    outer edges (edges.py; co-located antennas only)."""

    visibility: bool = True
    opacity: float = 0.9
    margin_m: float = 0.0025
    t_stop: float = 1e-4
    colocated_tol_m: float = 0.01
    polarisation: str = "V"
    link_chunk: int = 64
    second_order: bool = True
    third_order: bool = True
    min_patch_area_m2: float = 2e-3
    lit_threshold: float = 0.2
    edge_waves: bool = False


def lit_state(transmittance: torch.Tensor, threshold: float) -> torch.Tensor:
    """V [Q] of one leg from its traced transmittance [Q]: 1 where it exceeds `threshold`, else 0
    (threshold 0: the transmittance itself).

    Physical optics lights a facet or shadows it; Gaussians make soft shadows instead: a ray through
    one tiled surface keeps about 1 - opacity (0.03-0.1 at opacity 0.9), and one that passes near a
    surface's edge is dimmed by the tails of the edge Gaussians, which reach past the edge. Kept
    soft, the first lets the far faces of a solid shine through and the second dims faces beside an
    edge; the threshold lies between those two errors (docs/physics.md section 8.6)."""
    if threshold <= 0:
        return transmittance
    return (transmittance > threshold).to(transmittance.dtype)


def traced_lit(provider: OcclusionProvider, origins: torch.Tensor, gauss: torch.Tensor, settings: PairSettings,
               num_gaussians: int) -> torch.Tensor:
    """V [Q] of one leg: the lit state (lit_state) of surfel gauss [Q] from the antenna at origins [Q, 3] m,
    traced through the Gaussians with settings' opacity and margin (docs/physics.md section 8.6).
    The one definition of a surfel's lit state: the first order, the edge waves and (through the pairs'
    table) the double bounce use it."""
    op = torch.full((num_gaussians,), settings.opacity, dtype=torch.float64)
    return lit_state(provider.segment_transmittance(origins, gauss, settings.margin_m, op,
                                                    lit_stop(settings.t_stop, settings.lit_threshold)),
                    settings.lit_threshold)


def build_pairs(geom: FrozenGeometry, links: LinkSet, tx_ant: AntennaPattern, rx_ant: AntennaPattern,
                provider: OcclusionProvider | None, settings: PairSettings = PairSettings(),
                areas_m2: torch.Tensor | None = None, patches: "Patches | None" = None,
                labels: torch.Tensor | None = None) -> PairGeometry:
    """Trace once and keep the geometry of every lit (link, surfel) pair (see PairGeometry), and the
    double and triple bounces between planar patches when settings.second_order and their edge waves when
    settings.edge_waves (patches: computed from the geometry, and labels when given, unless passed)."""
    with torch.no_grad():
        area = surfel_areas(geom.means, geom.log_scales, geom.rotations, geom.normals) \
            if areas_m2 is None else areas_m2.double()
        cells = footprint_cells(geom.log_scales, geom.rotations, geom.normals, area)
        with single_thread_torch():   # ~100 small tensor ops per block: a second thread on a busy CPU costs more
            parts = [_pairs_block(geom, links, a, min(links.num, a + settings.link_chunk), tx_ant, rx_ant, cells,
                                  settings) for a in range(0, links.num, settings.link_chunk)]
        cat = {k: torch.cat([p[k] for p in parts]) for k in parts[0]}
        vis = torch.ones_like(cat["d_i"])
        if settings.visibility and provider is not None and cat["link"].numel():
            v_tx = traced_lit(provider, links.tx_m[cat["link"]], cat["gauss"], settings, geom.num)
            colocated = bool(((links.tx_m - links.rx_m).norm(dim=-1) < settings.colocated_tol_m).all())
            vis = v_tx if colocated else v_tx * traced_lit(provider, links.rx_m[cat["link"]], cat["gauss"], settings,
                                                           geom.num)
        keep = vis > 1e-6
        cat = {k: v[keep] for k, v in cat.items()}
        pairs = PairGeometry(links.num, cat["link"], cat["gauss"], cat["d_i"], cat["d_o"], cat["cos_i"], cat["cos_o"],
                             cat["te"], cat["gain"], vis[keep], cat["q_cell"], area[cat["gauss"]],
                             links.freq_hz.double())
        if (settings.second_order or settings.edge_waves) and patches is None:
            patches = planar_patches(geom, area, labels, settings.min_patch_area_m2)
        if settings.edge_waves:
            if getattr(patches, "edges", None) is None:   # found once per set of patches (prediction reuses them)
                patches.edges = patch_edges(geom, covariance(geom.log_scales, geom.rotations), cells, patches)
            pairs.edges = edge_terms(patches.edges, links, tx_ant, rx_ant, _edge_lit(geom, links, provider, settings, pairs),
                                     settings.polarisation, settings.colocated_tol_m)
        if settings.second_order:
            with single_thread_torch():   # many small tensor ops per patch: thread hand-offs cost more than the work
                pairs.double = build_double_bounce(
                    geom, links, tx_ant, rx_ant, patches, area, cells,
                    lambda lk, gs: pairs.visibility_of(lk, gs, geom.num), settings.polarisation,
                    settings.colocated_tol_m)
                if settings.third_order:
                    pairs.triple = build_triple_bounce(
                        geom, links, tx_ant, rx_ant, patches, area, cells,
                        lambda lk, gs: pairs.visibility_of(lk, gs, geom.num), settings.polarisation,
                        settings.colocated_tol_m)
        return pairs


def _edge_lit(geom: FrozenGeometry, links: LinkSet, provider: OcclusionProvider | None, settings: PairSettings,
              pairs: PairGeometry):
    """lit(link [Q], gauss [Q]) -> V [Q] of the edge waves: the surfel's lit state from the link's
    transmitter (co-located antennas: one path), whatever the surfel's orientation; 1 without visibility.

    With every link co-located the pairs' table already holds that state (V_tx) for each surfel facing
    the radar (a pair; 0 when it was shadowed and dropped): only surfels seen edge-on, which make no
    pair, are traced."""
    colocated = bool(((links.tx_m - links.rx_m).norm(dim=-1) < settings.colocated_tol_m).all())

    def trace(link: torch.Tensor, gauss: torch.Tensor) -> torch.Tensor:
        return traced_lit(provider, links.tx_m[link], gauss, settings, geom.num)

    def lit(link: torch.Tensor, gauss: torch.Tensor) -> torch.Tensor:
        if not settings.visibility or provider is None or link.numel() == 0:
            return torch.ones(link.shape, dtype=torch.float64)
        if not colocated:
            return trace(link, gauss)
        # a pair exists where _pairs_block's orientation test passes (the same expressions, per query)
        to_tx = links.tx_m[link] - geom.means[gauss]
        w_i = to_tx / to_tx.norm(dim=-1)[..., None]
        to_rx = links.rx_m[link] - geom.means[gauss]
        w_o = to_rx / to_rx.norm(dim=-1)[..., None]
        n0 = geom.normals[gauss]
        n = n0 * torch.where((w_i * n0).sum(-1) >= 0, 1.0, -1.0)[..., None]
        paired = ((w_i * n).sum(-1) > 1e-6) & ((w_o * n).sum(-1) > 1e-6)
        out = pairs.visibility_of(link, gauss, geom.num).clone()
        if bool((~paired).any()):
            out[~paired] = trace(link[~paired], gauss[~paired])
        return out
    return lit


def _pairs_block(geom, links: LinkSet, a: int, b: int, tx_ant, rx_ant, cells, settings: PairSettings) -> dict:
    """Lit pairs of links a..b-1 (dense over Gaussians, then filtered)."""
    tx, rx = links.tx_m[a:b], links.rx_m[a:b]
    to_tx = tx[:, None] - geom.means[None]          # [m, G, 3]
    d_i = to_tx.norm(dim=-1)
    w_i = to_tx / d_i[..., None]
    to_rx = rx[:, None] - geom.means[None]
    d_o = to_rx.norm(dim=-1)
    w_o = to_rx / d_o[..., None]
    n0 = geom.normals[None].expand_as(w_i)
    side = torch.where((w_i * n0).sum(-1) >= 0, 1.0, -1.0)
    n = n0 * side[..., None]                          # two-sided: the normal faces the transmitter
    cos_i = (w_i * n).sum(-1)
    cos_o = (w_o * n).sum(-1)
    lit = (cos_i > 1e-6) & (cos_o > 1e-6)
    m_idx, g_idx = lit.nonzero(as_tuple=True)
    wi, wo, nn_ = w_i[m_idx, g_idx], w_o[m_idx, g_idx], n[m_idx, g_idx]
    q = wi + wo
    q_cell = torch.einsum("pcj,pj->pc", cells[g_idx], q)
    g_t = tx_ant.gain(-wi, links.tx_axis[a:b][m_idx])
    g_r = rx_ant.gain(-wo, links.rx_axis[a:b][m_idx])
    return {"link": m_idx + a, "gauss": g_idx, "d_i": d_i[m_idx, g_idx], "d_o": d_o[m_idx, g_idx],
            "cos_i": cos_i[m_idx, g_idx], "cos_o": cos_o[m_idx, g_idx], "te": te_share(wi, nn_, settings.polarisation),
            "gain": torch.sqrt(g_t * g_r), "q_cell": q_cell}


def _sigmoid_range(theta: torch.Tensor, lo: float, hi: float) -> torch.Tensor:
    return lo + (hi - lo) * torch.sigmoid(theta)


def _logit_range(value: float, lo: float, hi: float) -> float:
    p = min(max((value - lo) / (hi - lo), 1e-6), 1 - 1e-6)
    return math.log(p / (1 - p))


@dataclass
class MaterialValues:
    """Physical values of N materials: eps_r [N], sigma at 1 GHz [N] S/m, conductivity exponent d,
    scattering coefficient S [N] in [0, 1), thickness [N] m (None: half-spaces)."""

    eps_r: torch.Tensor
    sigma_1ghz: torch.Tensor
    sigma_exponent: float
    scattering: torch.Tensor
    thickness_m: torch.Tensor | None

    def eta(self, freq_hz: torch.Tensor) -> torch.Tensor:
        """Complex relative permittivity [N, K]: eps_r - j sigma(f) / (eps_0 omega), sigma = sigma_1GHz f^d."""
        return law_permittivity(self.eps_r[:, None], 0.0, self.sigma_1ghz[:, None], self.sigma_exponent,
                                freq_hz.double()[None])

    def normal_reflection(self, freq_hz: torch.Tensor) -> torch.Tensor:
        """R_TE at normal incidence [N, K] (|Gamma| as a radio engineer reads it)."""
        k0 = 2 * math.pi * freq_hz.double()[None] / C0
        th = None if self.thickness_m is None else self.thickness_m[:, None]
        return fresnel(self.eta(freq_hz), 1.0, k0, th)[0]


class MaterialParams(nn.Module):
    """Learnable materials with parametrisations that keep every value physical.

    eps_r = 1 + (EPS_R_MAX - 1) sigmoid(t_eps); log10 sigma_1GHz in LOG10_SIGMA via a sigmoid;
    S = sigmoid(t_s); thickness log-uniform in THICKNESS_M via a sigmoid (or half-spaces);
    gain_db: a system gain in dB (learned only when asked). shared_scattering: one S for every material,
    sigmoid of the mean of t_s (t_s keeps one entry per material, so that states and swaps of a material's
    values keep their shapes; set_values sets every entry)."""

    def __init__(self, num_materials: int, *, eps_r: float = 3.0, sigma_1ghz: float = 0.01, scattering: float = 0.1,
                 thickness_m: float | None = 0.05, sigma_exponent: float = 1.0, shared_scattering: bool = False):
        super().__init__()
        self.shared_scattering = bool(shared_scattering)
        full = lambda v: nn.Parameter(torch.full((num_materials,), float(v), dtype=torch.float64))  # noqa: E731
        self.t_eps = full(_logit_range(eps_r, 1.0, EPS_R_MAX))
        self.t_sig = full(_logit_range(math.log10(sigma_1ghz), *LOG10_SIGMA))
        self.t_s = full(_logit_range(scattering, 0.0, 1.0))
        self.half_space = thickness_m is None
        lo, hi = (math.log(x) for x in THICKNESS_M)
        self.t_th = full(_logit_range(math.log(thickness_m or 0.05), lo, hi))
        self.gain_db = nn.Parameter(torch.zeros((), dtype=torch.float64))
        self.sigma_exponent = float(sigma_exponent)

    @property
    def num(self) -> int:
        return int(self.t_eps.numel())

    def values(self) -> MaterialValues:
        lo, hi = (math.log(x) for x in THICKNESS_M)
        return MaterialValues(
            eps_r=_sigmoid_range(self.t_eps, 1.0, EPS_R_MAX),
            sigma_1ghz=10 ** _sigmoid_range(self.t_sig, *LOG10_SIGMA),
            sigma_exponent=self.sigma_exponent,
            scattering=torch.sigmoid(self.t_s.mean()).expand(self.num) if self.shared_scattering else torch.sigmoid(self.t_s),
            thickness_m=None if self.half_space else torch.exp(_sigmoid_range(self.t_th, lo, hi)))

    def set_values(self, index: int, *, eps_r=None, sigma_1ghz=None, scattering=None, thickness_m=None) -> None:
        """Set material `index` (a start of the fit or a prior); with shared_scattering, S of every material."""
        with torch.no_grad():
            if eps_r is not None:
                self.t_eps[index] = _logit_range(float(eps_r), 1.0, EPS_R_MAX)
            if sigma_1ghz is not None:
                self.t_sig[index] = _logit_range(math.log10(max(float(sigma_1ghz), 1e-12)), *LOG10_SIGMA)
            if scattering is not None:
                self.t_s[slice(None) if self.shared_scattering else index] = _logit_range(float(scattering), 0.0, 1.0)
            if thickness_m is not None and not self.half_space:
                lo, hi = (math.log(x) for x in THICKNESS_M)
                self.t_th[index] = _logit_range(math.log(float(thickness_m)), lo, hi)


def scattered_power(pairs: PairGeometry, material_of_gaussian: torch.Tensor, mats: MaterialValues,
                    gain_db: torch.Tensor | float = 0.0, freq_hz: torch.Tensor | None = None,
                    surfel_factor: torch.Tensor | None = None) -> torch.Tensor:
    """Received power [M, K] (P_T = 1 W; path gain) of the model in the module docstring.

    material_of_gaussian [G] int64: the material of each Gaussian. freq_hz [K] (default: the
    frequencies the pairs were built for; only the phase, the footprint and Gamma depend on it).
    surfel_factor [G] complex: each surfel's specular term times (1 + surfel_factor) (the per-Gaussian
    residual of residual.py; None: the physical model alone)."""
    field, diffuse = scattered_field(pairs, material_of_gaussian, mats, freq_hz, surfel_factor)
    return (abs2(field) + diffuse) * 10 ** (torch.as_tensor(gain_db, dtype=torch.float64) / 10)


def specular_terms(pairs: PairGeometry, material_of_gaussian: torch.Tensor, mats: MaterialValues,
                   freq_hz: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """(first-order specular term of each pair [P, K] complex, Gamma [P, K]) (module docstring)."""
    f = pairs.freq_hz if freq_hz is None else freq_hz.double()
    k0 = 2 * math.pi * f / C0                                      # [K]
    mat = material_of_gaussian[pairs.gauss]                        # [P]
    eta = mats.eta(f)[mat]                                         # [P, K]
    th = None if mats.thickness_m is None else mats.thickness_m[mat][:, None]
    r_te, r_tm = fresnel(eta, pairs.cos_i[:, None], k0[None], th)
    gamma = co_polar_reflection(r_te, r_tm, pairs.te_share[:, None])   # [P, K]
    s = mats.scattering[mat]
    base = pairs.gain * pairs.vis * pairs.area / (4 * math.pi * pairs.d_i * pairs.d_o)   # [P]
    spec_amp = base * 0.5 * (pairs.cos_i + pairs.cos_o) * specular_share(s)
    foot = footprint_factor(pairs.q_cell, k0)
    phase = torch.exp(-1j * (pairs.d_i + pairs.d_o)[:, None] * k0[None])
    return 1j * (spec_amp[:, None] * foot) * gamma * phase, gamma


def scattered_field(pairs: PairGeometry, material_of_gaussian: torch.Tensor, mats: MaterialValues,
                    freq_hz: torch.Tensor | None = None, surfel_factor: torch.Tensor | None = None
                    ) -> tuple[torch.Tensor, torch.Tensor]:
    """(coherent field [M, K] complex: first, second and third order, diffuse power [M, K]) without the
    system gain; arguments as scattered_power."""
    f = pairs.freq_hz if freq_hz is None else freq_hz.double()
    k0 = 2 * math.pi * f / C0                                      # [K]
    terms, gamma = specular_terms(pairs, material_of_gaussian, mats, freq_hz)
    if surfel_factor is not None:
        terms = terms * (1.0 + surfel_factor[pairs.gauss])[:, None]
    field = torch.zeros((pairs.num_links, f.numel()), dtype=torch.complex128).index_add(0, pairs.link, terms)
    if pairs.double is not None and pairs.double.num:
        if freq_hz is not None and not torch.equal(f, pairs.double.freq_hz):
            raise ValueError("the double bounces were built for other frequencies")
        field = field + _double_bounce_field(pairs.double, material_of_gaussian, mats, k0)
    if pairs.triple is not None and pairs.triple.num:
        tb = pairs.triple
        field = field + _bounce_field(tb.num_links, tb.link, tb.gauss.unbind(1), tb.cos.unbind(1), tb.pol,
                                      tb.coef(k0), material_of_gaussian, mats, f, k0)
    if pairs.edges is not None and pairs.edges.num:
        if freq_hz is not None and not torch.equal(f, pairs.edges.freq_hz):
            raise ValueError("the edge waves were built for other frequencies")
        field = field + edge_field(pairs.edges, material_of_gaussian, mats)
    lam = C0 / f                                                   # [K] m
    s = mats.scattering[material_of_gaussian[pairs.gauss]]
    base = pairs.gain * pairs.vis * pairs.area / (4 * math.pi * pairs.d_i * pairs.d_o)   # [P]
    # G_T G_R V^2 S^2 |Gamma|^2 A cos_i cos_o lambda^2 / (16 pi^3 d_i^2 d_o^2) = base^2 S^2 |Gamma|^2 cos_i cos_o
    # lambda^2 / (pi A)
    diff_terms = (base**2 * s**2 * pairs.cos_i * pairs.cos_o / (math.pi * pairs.area))[:, None] \
        * abs2(gamma) * lam[None] ** 2
    diffuse = torch.zeros((pairs.num_links, f.numel()), dtype=torch.float64).index_add(0, pairs.link, diff_terms)
    return field, diffuse


def _double_bounce_field(db: DoubleBounce, material_of_gaussian: torch.Tensor, mats: MaterialValues,
                         k0: torch.Tensor) -> torch.Tensor:
    """Second-order field [M, K]: sum of coef sum_X R_X(A) sqrt(1 - S_A^2) (sum_Y b_XY R_Y(B) sqrt(1 - S_B^2)
    + b_X0) per link (b = db.pol, second_order.second_bounce_factors; b_X0 is the PO radiation of the wave
    that reaches B, which B's roughness does not scale): `_bounce_field` of two planes."""
    return _bounce_field(db.num_links, db.link, (db.gauss_a, db.gauss_b), (db.cos_a, db.cos_b), db.pol, db.coef,
                         material_of_gaussian, mats, db.freq_hz, k0)


def _bounce_field(num_links: int, link: torch.Tensor, gauss: tuple, cos: tuple, pol: torch.Tensor, coef: torch.Tensor,
                  material_of_gaussian: torch.Tensor, mats: MaterialValues, freq_hz: torch.Tensor,
                  k0: torch.Tensor) -> torch.Tensor:
    """Field [M, K] of I multiple-bounce items over N planes: per link the sum of coef [I, K] times
    `bounce_product` of the factors pol [I, F] (second_order.bounce_factors) and each plane's reflection
    coefficients R_TE, R_TM sqrt(1 - S^2) (the material of gauss[n] [I] at the incidence cosine cos[n] [I])."""
    eta = mats.eta(freq_hz)
    refl = []
    for g, c in zip(gauss, cos):
        mat = material_of_gaussian[g]
        th = None if mats.thickness_m is None else mats.thickness_m[mat][:, None]
        r_te, r_tm = fresnel(eta[mat], c[:, None], k0[None], th)
        spec = specular_share(mats.scattering[mat])[:, None]
        refl.append((r_te * spec, r_tm * spec))
    out = torch.zeros((num_links, freq_hz.numel()), dtype=torch.complex128)
    return out.index_add(0, link, coef * bounce_product(pol[:, :, None], refl))


def bounce_product(pol: torch.Tensor, refl: list) -> torch.Tensor:
    """[I, K]: sum_X1..X(N-1) R_X1(1) ... R_X(N-1)(N-1) (sum_XN c_X1..XN R_XN(N) + c_X1..X(N-1),0), the
    reflections of a multiple bounce over N planes with its physical-optics factors pol [I, F, K or 1]
    (F = 2^N + 2^(N-1), second_order.bounce_factors' order) and refl: N pairs (R_TE, R_TM) [I, K];
    one definition for the exact and the aggregated sums, of the double and the triple bounce."""
    full = 1 << len(refl)
    c = pol.unbind(1)
    te, tm = refl[-1]
    acc = [c[2 * q] * te + c[2 * q + 1] * tm + c[full + q] for q in range(full // 2)]   # 2^(N-1) of [I, K]
    for te, tm in reversed(refl[:-1]):
        acc = [te * acc[2 * q] + tm * acc[2 * q + 1] for q in range(len(acc) // 2)]
    return acc[0]


ANGLE_NODES = 46   # incidence-angle nodes of the aggregated form: 2 degree steps from 0 to 90 degrees
DOUBLE_NODES = 19  # ... of its double bounces: 5 degree steps (two angles per item: fewer cells)
DOUBLE_CULL_REL = 0.01  # per link, the weakest double-bounce cells carrying 1 % of its sum of magnitudes are dropped


def _aggregate_bounces(link: torch.Tensor, gauss: tuple, cos: tuple, pol: torch.Tensor, coef: torch.Tensor,
                       material_of_gaussian: torch.Tensor, n: int, j: int, cull_rel: float) -> dict:
    """Multiple-bounce items (N planes: gauss, cos N tensors [I]; pol [I, F]; coef [I, K]) summed per cell
    (link, material and angle node of each plane), each item split multilinearly between the 2^N node
    combinations around its incidence angles, with its factors pol (`bounce_product`).
    Per link the weakest cells carrying `cull_rel` of its sum of magnitudes are dropped (cost).
    Returns link [C], mat [C, N], node [C, N], pol [C, F, K]."""
    ends = []
    for g, c in zip(gauss, cos):
        lo, w_hi = AngleNodes(j).position(c)
        ends.append((material_of_gaussian[g], lo, w_hi))
    keys, weights = [], []
    for corner in itertools.product((0, 1), repeat=len(ends)):
        key, weight = link, None
        for (mat, lo, w_hi), up in zip(ends, corner):
            key = (key * n + mat) * j + lo + up
            w = w_hi if up else 1 - w_hi
            weight = w if weight is None else weight * w
        keys.append(key)
        weights.append(weight)
    key = torch.cat(keys)
    num = int(link.numel())
    uniq, inv = torch.unique(key, return_inverse=True)
    sums = torch.zeros((uniq.numel(), pol.shape[1], coef.shape[1]), dtype=torch.complex128)
    for q, w in enumerate(weights):
        part = inv[q * num:(q + 1) * num]
        sums.index_add_(0, part, (w[:, None] * pol)[:, :, None] * coef[:, None, :])
    mats_, nodes, rest = [], [], uniq
    for _ in ends:
        nodes.append(rest % j)
        rest = rest // j
        mats_.append(rest % n)
        rest = rest // n
    keep = _strong_cells(rest, sums.abs().sum(1).max(1).values, cull_rel)
    return {"link": rest[keep], "mat": torch.stack(mats_[::-1], 1)[keep], "node": torch.stack(nodes[::-1], 1)[keep],
            "pol": sums[keep]}


def _strong_cells(link: torch.Tensor, mag: torch.Tensor, rel: float) -> torch.Tensor:
    """[C] bool: per link, all cells but the weakest ones whose magnitudes sum to at most `rel` of the
    link's total (|Gamma| <= 1, so the dropped field is at most rel times the link's sum of magnitudes)."""
    order = torch.argsort(link.double() * (mag.max() * 2 + 1) + mag)      # by link, then magnitude ascending
    l_sorted, m_sorted = link[order], mag[order]
    cum = torch.cumsum(m_sorted, 0)
    first = torch.searchsorted(l_sorted, l_sorted)                          # start of each link's run
    before = torch.where(first > 0, cum[(first - 1).clamp(min=0)], torch.zeros_like(cum))
    total = torch.zeros(int(link.max()) + 1, dtype=mag.dtype).index_add(0, link, mag)
    keep_sorted = (cum - before) > rel * total[l_sorted]
    keep = torch.zeros_like(keep_sorted)
    keep[order] = keep_sorted
    return keep


@dataclass
class AggregatedPairs:
    """The pairs summed per (link, material, incidence-angle node) once, for fast fits with few materials.

    Gamma depends on a pair only through its material and incidence angle. With Gamma linear in the
    angle between nodes theta_j = j * 90 / (ANGLE_NODES - 1) degrees, every pair's geometric factor
    is split between its two neighbouring nodes, and the sums
        A_te[m, n, j, k] = sum_p c_p(k) te_p w_pj,  A_tm[...] = sum_p c_p(k) (1 - te_p) w_pj,
        D[m, n, j, :] = sum_p d_p w_pj (te_p^2, (1 - te_p)^2, te_p (1 - te_p))
    (c_p the complex specular factor without Gamma and sqrt(1 - S^2), d_p the diffuse factor without
    S^2 |Gamma|^2 lambda^2) make a fit step cost links x materials x nodes instead of pairs.
    The result equals `scattered_power` with Gamma interpolated linearly in angle (|Gamma|^2 too, for
    the diffuse part, |te R_TE - (1 - te) R_TM|^2 expanded in the three te moments): tests/model compare
    the two."""

    a_te: torch.Tensor      # [M, N, J, K] complex
    a_tm: torch.Tensor      # [M, N, J, K] complex
    diffuse: torch.Tensor   # [M, N, J, 3] real
    freq_hz: torch.Tensor   # [K]
    double: dict | None = None   # second order in cells (_aggregate_bounces): link [C], mat, node [C, 2], pol [C, 6, K]
    edges: torch.Tensor | None = None   # edge waves per (link, material) [M, N, K] complex (edges.aggregate_edges)
    triple: dict | None = None   # third order in cells: link [C], mat, node [C, 3], pol [C, 12, K]

    @staticmethod
    def build(pairs: PairGeometry, material_of_gaussian: torch.Tensor, num_materials: int,
              chunk: int = 1 << 20, double_cull_rel: float = DOUBLE_CULL_REL,
              edge_waves: bool = True) -> "AggregatedPairs":
        """edge_waves: include the pairs' edge items (False: leave them out, as if built without)."""
        m, n, j, k = pairs.num_links, num_materials, ANGLE_NODES, int(pairs.freq_hz.numel())
        k0 = 2 * math.pi * pairs.freq_hz / C0
        a_te = torch.zeros(m * n * j, k, dtype=torch.complex128)
        a_tm = torch.zeros_like(a_te)
        diff = torch.zeros(m * n * j, 3, dtype=torch.float64)
        with torch.no_grad():
            for a in range(0, pairs.num_pairs, chunk):
                sl = slice(a, min(pairs.num_pairs, a + chunk))
                cos_i, cos_o = pairs.cos_i[sl], pairs.cos_o[sl]
                base = pairs.gain[sl] * pairs.vis[sl] * pairs.area[sl] / (4 * math.pi * pairs.d_i[sl] * pairs.d_o[sl])
                c = (1j * base * 0.5 * (cos_i + cos_o))[:, None] \
                    * footprint_factor(pairs.q_cell[sl], k0) \
                    * torch.exp(-1j * (pairs.d_i[sl] + pairs.d_o[sl])[:, None] * k0[None])
                d = base**2 * cos_i * cos_o / (math.pi * pairs.area[sl])
                lo, w_hi = AngleNodes(j).position(cos_i)
                te = pairs.te_share[sl]
                cell = (pairs.link[sl] * n + material_of_gaussian[pairs.gauss[sl]]) * j + lo
                for node, w in ((cell, 1.0 - w_hi), (cell + 1, w_hi)):
                    a_te.index_add_(0, node, c * (te * w)[:, None])
                    a_tm.index_add_(0, node, c * ((1.0 - te) * w)[:, None])
                    diff.index_add_(0, node, (d * w)[:, None] * torch.stack([te**2, (1 - te) ** 2, te * (1 - te)], 1))
        db, tb = pairs.double, pairs.triple
        double = None if db is None or not db.num else \
            _aggregate_bounces(db.link, (db.gauss_a, db.gauss_b), (db.cos_a, db.cos_b), db.pol, db.coef,
                               material_of_gaussian, n, DOUBLE_NODES, double_cull_rel)
        triple = None if tb is None or not tb.num else \
            _aggregate_bounces(tb.link, tb.gauss.unbind(1), tb.cos.unbind(1), tb.pol, tb.coef(k0), material_of_gaussian,
                               n, DOUBLE_NODES, double_cull_rel)
        edges = aggregate_edges(pairs.edges, material_of_gaussian, n) \
            if edge_waves and pairs.edges is not None and pairs.edges.num else None
        return AggregatedPairs(a_te.reshape(m, n, j, k), a_tm.reshape(m, n, j, k), diff.reshape(m, n, j, 3),
                               pairs.freq_hz, double, edges, triple)

    def select_links(self, rows) -> "AggregatedPairs":
        """The aggregated sums of links `rows` (renumbered 0..len(rows)-1)."""
        r = torch.as_tensor(np.asarray(rows), dtype=torch.int64)

        def cells(d):
            if d is None:
                return None
            _, keep, new_link = renumber_links(d["link"], self.a_te.shape[0], r)
            out = {key: v[keep] for key, v in d.items()}
            out["link"] = new_link
            return out
        return AggregatedPairs(self.a_te[r], self.a_tm[r], self.diffuse[r], self.freq_hz, cells(self.double),
                               None if self.edges is None else self.edges[r], cells(self.triple))

    def power(self, mats: MaterialValues, gain_db: torch.Tensor | float = 0.0) -> torch.Tensor:
        """Received power [M, K] (P_T = 1 W) for materials `mats` (N of them)."""
        f = self.freq_hz
        k0 = 2 * math.pi * f / C0
        nodes = AngleNodes(ANGLE_NODES).cosines()   # [J]
        th = None if mats.thickness_m is None else mats.thickness_m[:, None, None]
        r_te, r_tm = fresnel(mats.eta(f)[:, None, :], nodes[None, :, None], k0[None, None], th)   # [N, J, K]
        spec = specular_share(mats.scattering).to(torch.complex128)[:, None, None]
        field = torch.einsum("mnjk,njk->mk", self.a_te, r_te * spec) - torch.einsum("mnjk,njk->mk", self.a_tm, r_tm * spec)
        if self.double is not None or self.triple is not None:
            # cells (link, material and node of each plane): Gamma on the nodes, with sqrt(1 - S^2)
            nodes2 = AngleNodes(DOUBLE_NODES).cosines()
            d_te, d_tm = fresnel(mats.eta(f)[:, None, :], nodes2[None, :, None], k0[None, None], th)   # [N, J2, K]
            kk = f.numel()
            te_flat = (d_te * spec).reshape(-1, kk)                  # [N * J2, K]
            tm_flat = (d_tm * spec).reshape(-1, kk)
            for d in (self.double, self.triple):
                if d is None:
                    continue
                u = d["mat"] * DOUBLE_NODES + d["node"]              # [C, N]
                refl = [(te_flat.index_select(0, u[:, p]), tm_flat.index_select(0, u[:, p]))   # cheap backward
                        for p in range(u.shape[1])]
                field = field.index_add(0, d["link"], bounce_product(d["pol"], refl))
        if self.edges is not None:
            field = field + torch.einsum("mnk,nk->mk", self.edges, edge_reflection(mats, f))
        # diffuse: |te R_TE - (1 - te) R_TM|^2 = te^2 |R_TE|^2 + (1-te)^2 |R_TM|^2 - 2 te (1-te) Re(R_TE R_TM*)
        moments = torch.stack([abs2(r_te), abs2(r_tm), -2.0 * (r_te * r_tm.conj()).real], -1)   # [N, J, K, 3]
        # sum over (material, node, moment) as one [M, N J 3] x [N J 3, K] product (batched tiny products are slow)
        moments = (moments * (mats.scattering**2)[:, None, None, None]).permute(0, 1, 3, 2)   # [N, J, 3, K]
        lam2 = (C0 / f) ** 2
        diffuse = (self.diffuse.reshape(self.diffuse.shape[0], -1) @ moments.reshape(-1, f.numel())) * lam2[None]
        return (abs2(field) + diffuse) * 10 ** (torch.as_tensor(gain_db, dtype=torch.float64) / 10)
