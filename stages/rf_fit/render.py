"""The RF renderer: S(f) = sum_l c_l for a batch of links (docs/physics.md sections 4-5).

c_l = Gamma_l F(w_o, w_i, n_l; R_l) cos(theta_i) sqrt(G_T(u_l) A_l / (4 pi d_l^2)) V_l
      * a_l Tbar_l sqrt(G_R(w_l)) exp(-j k (d_l + r_l)) / (sqrt(4 pi) r_l)          (P_T = 1 W)

Shapes: M links, G Gaussians, K frequencies. Everything that depends only on the frozen geometry
is computed once in `build_cache` (the geometric amplitude, the lobe's base, path lengths, and the
occlusion hit tables); `render` then costs O(M G K + hits) and is differentiable in the RF
attributes (a, R, Gamma).

Transmittances from the hit tables, with RF opacities, alpha = min(a_m G_m, 0.99):
- V_l (Tx -> mean of l): product of (1 - alpha) over the segment's hits.
- Tbar_l = (sum_w G_l(w) T_l(w) dOmega + w_c T_c) / (sum_w G_l(w) dOmega + w_c): the receiver's
  grid rays w (grid.py) that meet l, T_l(w) the transmittance of ray w in front of l, plus the ray
  through l's mean (transmittance T_c) with the weight w_c of `center_ray_cells` grid cells.
  That extra node is our addition to docs/physics.md section 5.1: a Gaussian smaller than a grid cell may meet no
  grid ray at all, and with it Tbar stays defined and the 1 vs 0.5 degree results agree.
- Self-shadowing margin: occluders less than `self_shadow_margin_m` in front of the target are
  ignored (surfels of one surface overlap; a surface does not shadow itself).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from rfir_cli.physics.closed_forms import C0
from rfir_cli.physics.gaussian_rf import covariance, projected_cross_section_m2

from .antennas import AntennaPattern
from .grid import local_grid, rays_toward_sphere_batch
from .occlusion import FrozenGeometry, HitTable, OcclusionProvider

ALPHA_MAX = 0.99
PHASE_CACHE_MAX = 20_000_000  # complex entries of the cached phase (320 MB)


@dataclass
class LinkSet:
    """Links: tx_m / rx_m [M, 3] m, freq_hz [K], tx_axis / rx_axis [M, 3] unit antenna axes."""

    tx_m: torch.Tensor
    rx_m: torch.Tensor
    freq_hz: torch.Tensor
    tx_axis: torch.Tensor
    rx_axis: torch.Tensor

    @property
    def num(self) -> int:
        return int(self.tx_m.shape[0])


@dataclass
class Materials:
    """RF attributes per Gaussian: opacity a [G] in [0, 1], roughness R [G] >= 1, gamma [G] complex.

    Optional incoherent term (docs/rf-model.md "Diffuse term"): diffuse [G] in [0, 1] and
    diffuse_roughness [G] >= 1, or None (the coherent model of docs/physics.md sections 4-5 alone)."""

    opacity: torch.Tensor
    roughness: torch.Tensor
    gamma: torch.Tensor
    diffuse: torch.Tensor | None = None
    diffuse_roughness: torch.Tensor | None = None


@dataclass
class RenderSettings:
    """Knobs of the renderer.

    visibility: trace V and Tbar (False: V = Tbar = 1, the object seen without occlusion).
    grid_step_deg: receiver grid step [deg] (paper: 1). center_ray_cells: weight of the ray through
    the mean, in grid cells. self_shadow_margin_m [m]. alpha_min: smallest response traced.
    colocated_tol_m: Tx and Rx closer than this share one set of segments (T_c = V).
    learn_visibility: keep the hit tables so that V and Tbar follow the learned opacities
    (exact, costly: O(hits) per step); False: V and Tbar are traced once with the RF opacity
    `visibility_opacity` and frozen (the a_l factor of c_l is still learned), with early ray
    termination below transmittance `t_stop`.
    path_loss / phase (ablations, the paper's "without path-loss/phase terms", docs/physics.md section 10): False drops each
    Gaussian's own 1 / (d r) spreading (link means instead) / its exp(-j k (d + r)) phase (all in phase).
    """

    visibility: bool = True
    grid_step_deg: float = 1.0
    center_ray_cells: float = 1.0
    self_shadow_margin_m: float = 0.01
    alpha_min: float = 1e-3
    colocated_tol_m: float = 0.01
    learn_visibility: bool = False
    visibility_opacity: float = 0.9
    t_stop: float = 1e-4
    path_loss: bool = True
    phase: bool = True


@dataclass
class _Segments:
    pair: torch.Tensor       # [H] m * G + l
    occluder: torch.Tensor   # [H]
    response: torch.Tensor   # [H]


@dataclass
class _Rays:
    pair: torch.Tensor       # [H] m * G + gaussian hit
    occluder_j: torch.Tensor  # [H] index of the first hit of the same ray not in front of this one
    gaussian: torch.Tensor   # [H]
    response: torch.Tensor   # [H]
    weight: torch.Tensor     # [H] response * dOmega of the ray
    ray_first: torch.Tensor  # [H] index of the first hit of this hit's ray


@dataclass
class RenderCache:
    """Everything about links x Gaussians that does not depend on the RF attributes."""

    num_links: int
    num_gaussians: int
    freq_hz: torch.Tensor    # [K]
    amp_geo: torch.Tensor    # [M, G] sqrt(G_T A / (4 pi d^2)) cos_i sqrt(cos_o) sqrt(G_R) / (sqrt(4 pi) r)
    lobe_base: torch.Tensor  # [M, G] (1 + cos psi) / 2
    path_m: torch.Tensor     # [M, G] d + r
    seg_tx: _Segments | None = None
    seg_rx: _Segments | None = None   # None with co-located Tx/Rx: T_c = V
    rays: _Rays | None = None
    den: torch.Tensor | None = None    # [M * G] sum G dOmega + w_c
    w_c: float = 0.0
    phase: torch.Tensor | None = None       # [M, G, K] exp(-j k (d + r)) when small enough to keep
    v_fixed: torch.Tensor | None = None     # [M, G] frozen V (learn_visibility = False)
    tbar_fixed: torch.Tensor | None = None  # [M, G] frozen Tbar


def link_geometry(geom: FrozenGeometry, links: LinkSet, tx_ant: AntennaPattern, rx_ant: AntennaPattern,
                  path_loss: bool = True):
    """(amp_geo, lobe_base, path_m), each [M, G]; same conventions as bistatic_gaussian_response.

    path_loss=False (ablation): the 1 / (d r) spreading uses each link's mean distances instead of
    every Gaussian's own, so the amplitude no longer varies with distance across the object."""
    means, normals = geom.means, geom.normals
    to_g = means[None] - links.tx_m[:, None]
    d_in = to_g.norm(dim=-1)
    u_in = to_g / d_in[..., None]
    to_rx = links.rx_m[:, None] - means[None]
    r_out = to_rx.norm(dim=-1)
    w_o = to_rx / r_out[..., None]
    # Two-sided surfels: the normal n = side * n0 faces the Tx. With u.n0, w.n0 and w.u the cosines
    # follow without forming n: cos_i = -u.n, cos_o = w.n, cos_psi = w.reflect(u, n) = w.u - 2 (u.n0)(w.n0).
    un0 = torch.einsum("mgc,gc->mg", u_in, normals)
    wn0 = torch.einsum("mgc,gc->mg", w_o, normals)
    side = torch.where(un0 > 0, -1.0, 1.0)
    cos_i = (-side * un0).clamp(min=0.0)
    cos_o = side * wn0
    cos_psi = (w_o * u_in).sum(-1) - 2.0 * un0 * wn0
    area = projected_cross_section_m2(covariance(geom.log_scales, geom.rotations), u_in)
    g_t = tx_ant.gain(u_in, links.tx_axis[:, None])
    g_r = rx_ant.gain(-w_o, links.rx_axis[:, None])
    amp = torch.sqrt(g_t * area / (4 * math.pi * d_in**2)) * cos_i * torch.sqrt(cos_o.clamp(min=0.0)) \
        * torch.sqrt(g_r) / (math.sqrt(4 * math.pi) * r_out)
    if not path_loss:
        amp = amp * d_in * r_out / (d_in.mean(1, keepdim=True) * r_out.mean(1, keepdim=True))
    return amp, ((1.0 + cos_psi) / 2.0).clamp(min=0.0), d_in + r_out


def _segments(provider: OcclusionProvider, geom: FrozenGeometry, origins: torch.Tensor, margin: float) -> _Segments:
    """Hits on every (origin m, Gaussian l) segment, minus those within `margin` of the target."""
    m, g = origins.shape[0], geom.num
    pair_origin = origins.repeat_interleave(g, dim=0)
    target = torch.arange(g).repeat(m)
    hits = provider.segment_hits(pair_origin, target)
    length = (geom.means[target[hits.query]] - pair_origin[hits.query]).norm(dim=-1)
    hits = hits.select(hits.t_m < length - margin)
    return _Segments(hits.query, hits.gaussian, hits.response)


def _grid_directions(geom: FrozenGeometry, links: LinkSet, rx_ant: AntennaPattern, settings: RenderSettings):
    """Every receiver's grid rays toward the scene: (origins [R, 3], dirs [R, 3], dOmega [R] sr, link [R])."""
    centre = 0.5 * (geom.means.min(0).values + geom.means.max(0).values)
    radius = float((geom.means - centre).norm(dim=-1).max() + 4.0 * torch.exp(geom.log_scales).max())
    local_d, local_w = local_grid(settings.grid_step_deg, rx_ant.front_only)
    dirs, dom, link_of = rays_toward_sphere_batch(links.rx_m, links.rx_axis, centre, radius, local_d, local_w)
    return links.rx_m[link_of], dirs, dom, link_of


def _grid_rays(provider, geom, links: LinkSet, rx_ant: AntennaPattern, settings: RenderSettings,
               opacity: torch.Tensor | None = None):
    """Grid-ray hit tables of every receiver, and the static denominators of Tbar."""
    origins, dirs, dom, link_of = _grid_directions(geom, links, rx_ant, settings)
    hits: HitTable = provider.ray_hits(origins, dirs, opacity, settings.t_stop if opacity is not None else 0.0)
    g = geom.num
    n = hits.query.numel()
    idx = torch.arange(n)
    new_ray = torch.ones(n, dtype=torch.bool)
    if n:
        new_ray[1:] = hits.query[1:] != hits.query[:-1]
    ray_first = torch.cummax(torch.where(new_ray, idx, torch.zeros_like(idx)), 0).values
    # first hit of the same ray with t >= t_h - margin (hits are sorted by (ray, t))
    span = float(hits.t_m.max()) + 1.0 if n else 1.0
    key = hits.query.double() * span + hits.t_m
    j = torch.searchsorted(key, key - settings.self_shadow_margin_m)
    j = torch.maximum(j, ray_first)
    pair = link_of[hits.query] * g + hits.gaussian
    weight = hits.response * dom[hits.query]
    return _Rays(pair, j, hits.gaussian, hits.response, weight, ray_first)


def build_cache(geom: FrozenGeometry, links: LinkSet, tx_ant: AntennaPattern, rx_ant: AntennaPattern,
                provider: OcclusionProvider | None, settings: RenderSettings = RenderSettings(),
                frozen_opacity: torch.Tensor | None = None, cull: tuple[Materials, float] | None = None
                ) -> RenderCache:
    """Trace once and keep what the renderer needs while the geometry stays frozen.

    frozen_opacity [G]: RF opacities for the frozen V and Tbar (default: settings.visibility_opacity
    for every Gaussian); prediction passes the fitted ones.
    cull (prediction only, known materials, frozen visibility): (materials, rel). Per link, the
    weakest Gaussians, whose unoccluded magnitudes |c_l| sum to at most `rel` of the link's total,
    are dropped (c_l = 0) and their visibility is not traced. The error in S is at most
    rel * sum |c_l|, whatever the occlusion."""
    with torch.no_grad():
        amp, lobe, path = link_geometry(geom, links, tx_ant, rx_ant, settings.path_loss)
        keep = None
        if cull is not None and cull[1] > 0 and not settings.learn_visibility:
            keep = _cull_mask(amp, lobe, cull[0], cull[1])
            amp = amp * keep
        if not settings.phase:
            path = torch.zeros_like(path)
        cache = RenderCache(links.num, geom.num, links.freq_hz.double(), amp, lobe, path)
        if amp.numel() * len(links.freq_hz) <= PHASE_CACHE_MAX:
            k = 2 * math.pi * cache.freq_hz / C0
            cache.phase = torch.exp(-1j * path[..., None] * k)
        if not settings.visibility:
            return cache
        margin = settings.self_shadow_margin_m
        colocated = bool(((links.tx_m - links.rx_m).norm(dim=-1) < settings.colocated_tol_m).all())
        cache.w_c = settings.center_ray_cells * math.radians(settings.grid_step_deg) ** 2
        if settings.learn_visibility:
            cache.seg_tx = _segments(provider, geom, links.tx_m, margin)
            cache.seg_rx = None if colocated else _segments(provider, geom, links.rx_m, margin)
            cache.rays = _grid_rays(provider, geom, links, rx_ant, settings)
        else:
            a_vis = torch.full((geom.num,), settings.visibility_opacity, dtype=torch.float64) \
                if frozen_opacity is None else frozen_opacity.detach().double()
            target = torch.arange(geom.num).repeat(links.num)
            pairs = torch.arange(links.num * geom.num) if keep is None else keep.reshape(-1).nonzero()[:, 0]

            def traced(origins: torch.Tensor) -> torch.Tensor:
                out = torch.zeros(links.num * geom.num, dtype=torch.float64)
                out[pairs] = provider.segment_transmittance(origins[pairs // geom.num], target[pairs], margin,
                                                            a_vis, settings.t_stop)
                return out

            v = traced(links.tx_m)
            t_c = v if colocated else traced(links.rx_m)
            cache.den, tbar = _frozen_tbar(provider, geom, links, rx_ant, settings, a_vis, t_c, cache.w_c)
            shape = (links.num, geom.num)
            cache.v_fixed, cache.tbar_fixed = v.reshape(shape), tbar.reshape(shape)
            return cache
        den = torch.full((links.num * geom.num,), cache.w_c, dtype=torch.float64)
        den.index_add_(0, cache.rays.pair, cache.rays.weight)
        cache.den = den
    return cache


def _frozen_tbar(provider: OcclusionProvider, geom: FrozenGeometry, links: LinkSet, rx_ant: AntennaPattern,
                 settings: RenderSettings, opacity: torch.Tensor, t_c: torch.Tensor, w_c: float):
    """(den, Tbar), each [M * G], with fixed opacities [G]: the same sums as `_tbar` over the grid rays
    (stopped where their transmittance < t_stop), with each hit's transmittance in front of it
    composited by the provider instead of kept as tables."""
    origins, dirs, dom, link_of = _grid_directions(geom, links, rx_ant, settings)
    group_offsets = torch.searchsorted(link_of, torch.arange(links.num + 1))   # rays come grouped by link
    num, den = provider.footprint_sums(origins, dirs, group_offsets, dom, opacity, settings.t_stop,
                                       settings.self_shadow_margin_m)
    den = den.reshape(-1) + w_c
    num = num.reshape(-1) + w_c * t_c
    return den, torch.where(den > 0, num / den.clamp(min=1e-300), t_c)


def _cull_mask(amp: torch.Tensor, lobe: torch.Tensor, mats: Materials, rel: float) -> torch.Tensor:
    """[M, G] bool: the Gaussians that carry all but `rel` of each link's sum of |c_l| (unoccluded)."""
    mag = amp * lobe ** mats.roughness[None] * mats.opacity[None] * mats.gamma.abs()[None]
    if mats.diffuse is not None:
        mag = mag + amp * lobe ** mats.diffuse_roughness[None] * mats.opacity[None] * mats.diffuse[None]
    order = torch.argsort(mag, dim=1)
    tail = torch.cumsum(torch.gather(mag, 1, order), 1) / mag.sum(1, keepdim=True).clamp(min=1e-300)
    keep = torch.ones_like(mag, dtype=torch.bool)
    keep.scatter_(1, order, tail > rel)
    return keep


def _log1m_alpha(opacity: torch.Tensor, occluder: torch.Tensor, response: torch.Tensor) -> torch.Tensor:
    return torch.log1p(-(opacity[occluder] * response).clamp(max=ALPHA_MAX))


def _segment_transmittance(seg: _Segments, opacity: torch.Tensor, size: int) -> torch.Tensor:
    acc = torch.zeros(size, dtype=opacity.dtype).index_add(0, seg.pair, _log1m_alpha(opacity, seg.occluder,
                                                                                      seg.response))
    return torch.exp(acc)


def transmittances(cache: RenderCache, opacity: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(V, Tbar), each [M, G], differentiable in the RF opacities [G]."""
    shape = (cache.num_links, cache.num_gaussians)
    if cache.v_fixed is not None:
        return cache.v_fixed, cache.tbar_fixed
    if cache.seg_tx is None:
        one = torch.ones(shape, dtype=opacity.dtype)
        return one, one
    size = shape[0] * shape[1]
    v = _segment_transmittance(cache.seg_tx, opacity, size)
    t_c = v if cache.seg_rx is None else _segment_transmittance(cache.seg_rx, opacity, size)
    return v.reshape(shape), _tbar(cache, t_c, opacity).reshape(shape)


def _tbar(cache: RenderCache, t_c: torch.Tensor, opacity: torch.Tensor) -> torch.Tensor:
    """Footprint-averaged transmittance [M * G] from the grid rays plus the centre ray (T_c)."""
    num = cache.w_c * t_c
    if cache.rays is not None and cache.rays.pair.numel():
        r = cache.rays
        log1m = _log1m_alpha(opacity, r.gaussian, r.response)
        excl = torch.cumsum(log1m, 0) - log1m               # prefix sum before each hit
        t_before = torch.exp(excl[r.occluder_j] - excl[r.ray_first])
        num = num.index_add(0, r.pair, r.weight * t_before)
    return torch.where(cache.den > 0, num / cache.den.clamp(min=1e-300), t_c)


def render_power(cache: RenderCache, mats: Materials, freq_chunk: int = 64) -> torch.Tensor:
    """Received power [M, K] with P_T = 1 W: |S|^2 plus, when mats.diffuse is set, the incoherent term

    P_d = sum_l (amp_l a_l V_l Tbar_l D_l lobe_l^(R_d,l))^2, the power of each Gaussian's diffuse
    share D_l summed without phase (rough-surface scattering whose phase is random across the
    surface, as Sionna's diffuse paths combined as power); independent of frequency."""
    power = render(cache, mats, freq_chunk).abs() ** 2
    if mats.diffuse is None:
        return power
    v, tbar = transmittances(cache, mats.opacity)
    amp = cache.amp_geo * v * tbar * mats.opacity[None] * mats.diffuse[None] \
        * cache.lobe_base ** mats.diffuse_roughness[None]
    return power + (amp**2).sum(1, keepdim=True)


def render(cache: RenderCache, mats: Materials, freq_chunk: int = 64) -> torch.Tensor:
    """Received complex amplitude S [M, K] with P_T = 1 W (path gain = |S|^2)."""
    v, tbar = transmittances(cache, mats.opacity)
    lobe = cache.lobe_base ** mats.roughness[None]
    amp = cache.amp_geo * lobe * v * tbar * mats.opacity[None]        # [M, G] real
    weighted = amp.to(torch.complex128) * mats.gamma[None].to(torch.complex128)
    if cache.phase is not None:
        return torch.einsum("mg,mgk->mk", weighted, cache.phase)
    k_all = 2 * math.pi * cache.freq_hz / C0
    outs = []
    for a in range(0, k_all.shape[0], freq_chunk):
        k = k_all[a:a + freq_chunk]
        phase = torch.exp(-1j * cache.path_m[..., None] * k)            # [M, G, k]
        outs.append(torch.einsum("mg,mgk->mk", weighted, phase))
    return torch.cat(outs, 1)
