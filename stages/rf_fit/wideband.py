"""Wideband RF model (docs/physics.md section 7): one material set, each frequency's own k, and a
frequency-aware modulation network trained on top of it.

Model, for link m, Gaussian l, frequency f (P_T = 1 W):
    c_ml(f) = b_ml * lobe_ml^R_l(f) * |Gamma_l(f)| * exp(j angle_l(f)) * exp(-j k(f) (d_ml + r_ml))
    path gain dB = 10 log10 |sum_l c_ml(f)|^2 + s_tx(f)
with b_ml = amp_geo V Tbar a_l (render.py's frozen cache, a_l learned), k(f) = 2 pi f / c and
- base (step 1): R_l, |Gamma_l|, angle_l shared by every frequency (render.py's parametrisations:
  R = 1 + softplus(theta_R), |Gamma| = sigmoid(theta_g), angle = theta_phi);
- modulation (step 2): an MLP maps (embedding e_l, normalised frequency) to corrections
  (dtheta_R, dtheta_g, dtheta_phi) added to the raw parameters. Its last layer starts at zero, so
  the untrained network (or `use_network = False`) is the base model exactly.
- s_tx(f): the system gain [dB], piecewise linear over `knots` frequencies spanning the band,
  so that any frequency inside the band can be predicted (docs/rf-model.md: why it is learned).

The [M, G, K] complex tensor of a 2000-frequency band does not fit in memory: the renderer keeps
the (link, Gaussian) pairs that contribute (`PairCache`, [P]) and evaluates the phases of a few
frequencies at a time (training: a random subset per step; prediction: chunks).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from rfir_cli.physics.closed_forms import C0

from .params import RFParams
from .render import RenderCache, transmittances

OUTPUTS = 3  # dtheta_R, dtheta_g, dtheta_phi
USED_BASE = ("base.index", "base.theta_a", "base.theta_r", "base.theta_g", "base.theta_phi")


@dataclass
class PairCache:
    """Contributing (link, Gaussian) pairs of a RenderCache, frozen visibility.

    link [P], gaussian [P] int64; amp [P] = amp_geo V Tbar (without a_l); log_lobe [P] =
    log((1 + cos psi) / 2) (clamped at log 1e-300); path_m [P] = d + r [m]; num_links M.
    """

    link: torch.Tensor
    gaussian: torch.Tensor
    amp: torch.Tensor
    log_lobe: torch.Tensor
    path_m: torch.Tensor
    num_links: int

    def to(self, dtype: torch.dtype) -> PairCache:
        """The same pairs with real values in `dtype` (float32: about twice as fast, phase error ~1e-4 rad)."""
        return PairCache(self.link, self.gaussian, self.amp.to(dtype), self.log_lobe.to(dtype), self.path_m.to(dtype),
                         self.num_links)


def subset_links(pairs: PairCache, links: torch.Tensor) -> PairCache:
    """The pairs of the given links [B] (renumbered 0..B-1 in that order); pairs sorted by link."""
    starts = torch.searchsorted(pairs.link, torch.arange(pairs.num_links + 1))
    idx = torch.cat([torch.arange(int(starts[m]), int(starts[m + 1])) for m in links.tolist()])
    new_link = torch.repeat_interleave(torch.arange(len(links)), starts[links + 1] - starts[links])
    return PairCache(new_link, pairs.gaussian[idx], pairs.amp[idx], pairs.log_lobe[idx], pairs.path_m[idx], len(links))


def pairs_from_cache(cache: RenderCache, rel_floor: float = 0.0) -> PairCache:
    """Keep the pairs whose amp_geo V Tbar exceeds rel_floor times the largest of their link (0: all
    nonzero ones, exact). Uses the frozen V and Tbar (learn_visibility = False)."""
    with torch.no_grad():
        ones = torch.ones(cache.num_gaussians, dtype=torch.float64)
        v, tbar = transmittances(cache, ones) if cache.v_fixed is None else (cache.v_fixed, cache.tbar_fixed)
        amp = cache.amp_geo * v * tbar                                     # [M, G]
        keep = (amp > 0) & (cache.lobe_base > 0)
        if rel_floor > 0:
            keep &= amp >= rel_floor * amp.max(1, keepdim=True).values
        m, g = torch.nonzero(keep, as_tuple=True)
        log_lobe = torch.log(cache.lobe_base[m, g].clamp(min=1e-300))
        return PairCache(m, g, amp[m, g], log_lobe, cache.path_m[m, g], cache.num_links)


class SystemGain(nn.Module):
    """s_tx(f) [dB]: linear interpolation between `num_knots` values over [f_min, f_max] (held
    constant outside)."""

    def __init__(self, f_min_hz: float, f_max_hz: float, num_knots: int):
        super().__init__()
        self.f_min_hz, self.f_max_hz = float(f_min_hz), float(f_max_hz)
        self.knots_db = nn.Parameter(torch.zeros(max(int(num_knots), 1), dtype=torch.float64))

    def knot_freqs_hz(self) -> torch.Tensor:
        n = self.knots_db.numel()
        return torch.linspace(self.f_min_hz, self.f_max_hz, n, dtype=torch.float64) if n > 1 \
            else torch.tensor([0.5 * (self.f_min_hz + self.f_max_hz)], dtype=torch.float64)

    def forward(self, freq_hz: torch.Tensor) -> torch.Tensor:
        n = self.knots_db.numel()
        if n == 1:
            return self.knots_db.expand(freq_hz.shape[0])
        span = max(self.f_max_hz - self.f_min_hz, 1e-9)
        x = ((freq_hz - self.f_min_hz) / span).clamp(0, 1) * (n - 1)
        lo = x.floor().long().clamp(max=n - 2)
        w = x - lo
        return (1 - w) * self.knots_db[lo] + w * self.knots_db[lo + 1]


class ModulationNet(nn.Module):
    """(embedding [G, E], normalised frequency [K] in [-1, 1]) -> corrections [G, K, 3].

    The frequency enters as x and sin/cos(pi n x), n = 1..fourier. Per-Gaussian embeddings are
    learned (initialised N(0, 0.1^2)). Hidden layers: `layers` x `hidden` with SiLU. The last layer
    is zero at initialisation (network output 0: the base model)."""

    def __init__(self, num_gaussians: int, embed_dim: int = 8, hidden: int = 64, layers: int = 3, fourier: int = 4,
                 seed: int = 0):
        super().__init__()
        gen = torch.Generator().manual_seed(seed)
        self.fourier = int(fourier)
        self.embedding = nn.Parameter(0.1 * torch.randn(num_gaussians, embed_dim, generator=gen, dtype=torch.float64))
        dims = [embed_dim + 1 + 2 * self.fourier] + [hidden] * max(layers - 1, 0) + [OUTPUTS]
        mods = []
        for i in range(len(dims) - 1):
            lin = nn.Linear(dims[i], dims[i + 1], dtype=torch.float64)
            with torch.no_grad():
                bound = math.sqrt(6.0 / dims[i])
                lin.weight.copy_((torch.rand(lin.weight.shape, generator=gen, dtype=torch.float64) * 2 - 1) * bound)
                lin.bias.zero_()
            mods.append(lin)
        self.linears = nn.ModuleList(mods)
        with torch.no_grad():
            self.linears[-1].weight.zero_()

    def forward(self, x_freq: torch.Tensor) -> torch.Tensor:
        g, k = self.embedding.shape[0], x_freq.shape[0]
        n = torch.arange(1, self.fourier + 1, dtype=torch.float64)
        feats = torch.cat([x_freq[:, None], torch.sin(math.pi * n * x_freq[:, None]),
                           torch.cos(math.pi * n * x_freq[:, None])], 1)                # [K, 1 + 2F]
        h = torch.cat([self.embedding[:, None].expand(g, k, -1), feats[None].expand(g, k, -1)], -1)
        for lin in self.linears[:-1]:
            h = nn.functional.silu(lin(h))
        return self.linears[-1](h)                                                       # [G, K, 3]


class WidebandModel(nn.Module):
    """Base materials (RFParams, per-Gaussian sharing index), s_tx(f) and the modulation network."""

    def __init__(self, index: torch.Tensor, f_min_hz: float, f_max_hz: float, *, knots: int = 17,
                 init: dict | None = None, net: dict | None = None, seed: int = 0):
        super().__init__()
        self.base = RFParams(index, 0, **(init or {}))
        self.s_tx = SystemGain(f_min_hz, f_max_hz, knots)
        self.net = ModulationNet(int(index.numel()), seed=seed, **(net or {}))
        self.use_network = True

    def x_freq(self, freq_hz: torch.Tensor) -> torch.Tensor:
        """Normalised frequency in [-1, 1] over the band."""
        lo, hi = self.s_tx.f_min_hz, self.s_tx.f_max_hz
        return (2 * (freq_hz - lo) / max(hi - lo, 1e-9) - 1).to(torch.float64)

    def attributes(self, freq_hz: torch.Tensor):
        """(opacity [G], R [G, K], |Gamma| [G, K], angle [G, K] rad) at freq_hz [K]."""
        b, i = self.base, self.base.index
        k = freq_hz.shape[0]
        t_r, t_g, t_p = (p[i][:, None].expand(-1, k) for p in (b.theta_r, b.theta_g, b.theta_phi))
        if self.use_network:
            d = self.net(self.x_freq(freq_hz))
            t_r, t_g, t_p = t_r + d[..., 0], t_g + d[..., 1], t_p + d[..., 2]
        return torch.sigmoid(b.theta_a)[i], 1.0 + nn.functional.softplus(t_r), torch.sigmoid(t_g), t_p

    def field(self, pairs: PairCache, freq_hz: torch.Tensor) -> torch.Tensor:
        """S [M, K] complex at freq_hz [K] (P_T = 1 W), in the precision of the pairs (float64, or
        float32 for fast prediction: `PairCache.to(torch.float32)`)."""
        dt = pairs.amp.dtype
        opacity, rough, g_abs, g_ang = (t.to(dt) for t in self.attributes(freq_hz))
        g = pairs.gaussian
        k = (2 * math.pi * freq_hz / C0).to(dt)
        if not self.use_network:  # frequency-independent weights: one [P] complex weight, then the phases
            w = torch.polar(pairs.amp * opacity[g] * torch.exp(rough[g, 0] * pairs.log_lobe) * g_abs[g, 0], g_ang[g, 0])
            c = w[:, None] * torch.polar(torch.ones((), dtype=dt), -pairs.path_m[:, None] * k[None])
        else:
            mag = (pairs.amp * opacity[g])[:, None] * torch.exp(rough[g] * pairs.log_lobe[:, None]) * g_abs[g]
            c = torch.polar(mag, g_ang[g] - pairs.path_m[:, None] * k[None])                # [P, K]
        out = torch.zeros(pairs.num_links, freq_hz.shape[0], dtype=c.dtype)
        return out.index_add(0, pairs.link, c)

    def predict_db(self, pairs: PairCache, freq_hz: torch.Tensor) -> torch.Tensor:
        """Path gain [M, K] dB (float64)."""
        s = self.field(pairs, freq_hz)
        power = (s.real**2 + s.imag**2).double()
        return 10 * torch.log10(power + 1e-300) + self.s_tx(freq_hz)[None]

    def flat_state(self) -> dict:
        """state_dict as numpy arrays (for the artifact's free group model/)."""
        return {k: v.detach().cpu().numpy().copy() for k, v in self.state_dict().items()}


def load_flat_state(model: WidebandModel, flat: dict) -> None:
    """Inverse of flat_state. Every tensor the wideband model uses must be there with its shape;
    others (e.g. RFParams attributes added later and unused here) keep their initial values."""
    own = model.state_dict()
    used = [k for k in own if not k.startswith("base.") or k in USED_BASE]
    missing = [k for k in used if k not in flat]
    if missing:
        raise RuntimeError(f"missing tensors {missing[:3]}")
    model.load_state_dict({k: torch.as_tensor(v) for k, v in flat.items() if k in own}, strict=False)
