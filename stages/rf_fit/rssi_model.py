"""The RSSI model: direct path with visibility + RFIR-rendered NLoS part (docs/physics.md section 6).

For a link from x_t to x_r (omni antennas, P_T = 1 W, one frequency, k = 2 pi f / c):

    S = w(d, v) * v * lambda / (4 pi d) * exp(-j k d)  +  g_nlos * S_NLoS
    path gain [dB] = 10 log10 |S|^2 + s_tx_db

- d = |x_r - x_t| [m]; v in [0, 1] is the transmittance of the Tx-Rx segment through the Gaussians
  with the RF opacities the visibility was traced with (rfir_tracer, `los_transmittance`).
- w(d, v) = exp(h_0 + j h_1), (h_0, h_1) = a small MLP of (log d, v): the distance-aware network for
  transmit strength and attenuation. Its last layer starts at zero, so an untrained model's direct
  path is exactly free-space Friis times v (test). `weighting = False` (the ablation) fixes w = 1
  and v = 1: LoS and NLoS summed without the weighting.
- S_NLoS = sum_l c_l of docs/physics.md sections 4-5 (stages/rf_fit/render.py's conventions:
  `link_geometry` for the geometric amplitude, lobe base and path length), with learned a_l, R_l,
  Gamma_l; g_nlos = 10^(nlos_gain_db / 20) is a learned scale, because the rendering's absolute
  level depends on the Gaussian density (docs/rf-model.md), and s_tx_db the learned system gain.

Visibilities (deviation from docs/physics.md section 5.1, on purpose, for speed; docs/rssi.md): V_l (Tx ->
Gaussian l) is traced exactly per transmitter; the receiver-side Tbar_l is the transmittance from the
receiver to l's mean, interpolated trilinearly from a `ProbeField` traced once on a lattice of
probe points. Each receiver then costs no tracing, so a 440-point map for a new Tx costs one Tx
trace (G segments) plus 440 LoS segments.

Shapes: M links, G Gaussians, P probes. Tensors are float64 unless noted (cached [M, G] terms are
float32 / complex64 to fit in memory).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from rfir_cli.physics.closed_forms import C0
from rfir_cli.physics.gaussian_rf import covariance

from .antennas import AntennaPattern
from .occlusion import FrozenGeometry, OcclusionProvider, product_from_hits
from .params import RFParams

LOG_AMP_MAX = 6.0  # |h_0| bound in nepers (+-52 dB) keeps the direct-path weight finite


class LosNet(nn.Module):
    """(log d [m], v) [M, 2] -> (h_0 log-amplitude [Np], h_1 phase [rad]) [M, 2]; zero at start."""

    def __init__(self, hidden: int = 16):
        super().__init__()
        self.body = nn.Sequential(nn.Linear(2, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh())
        self.head = nn.Linear(hidden, 2)
        self.double()
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def forward(self, log_d: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        h = self.head(self.body(torch.stack([log_d, v], -1)))
        return torch.stack([LOG_AMP_MAX * torch.tanh(h[..., 0] / LOG_AMP_MAX), h[..., 1]], -1)


class RssiModel(nn.Module):
    """Learnable parts: per-Gaussian materials (RFParams, one frequency), the LoS network, the NLoS gain."""

    def __init__(self, index: torch.Tensor, *, weighting: bool = True, hidden: int = 16, opacity: float = 0.9,
                 roughness: float = 4.0, gamma_abs: float = 0.5, gamma_phase_rad: float = 0.0):
        super().__init__()
        self.rf = RFParams(index, 1, opacity=opacity, roughness=roughness, gamma_abs=gamma_abs,
                           gamma_phase_rad=gamma_phase_rad)
        self.los = LosNet(hidden)
        self.nlos_gain_db = nn.Parameter(torch.zeros((), dtype=torch.float64))
        self.weighting = bool(weighting)

    def groups(self, names: list[str]) -> list[dict]:
        """Optimiser groups: RFParams' names plus "los" and "nlos_gain"."""
        rf_names = [n for n in names if n not in ("los", "nlos_gain")]
        out = self.rf.groups(rf_names)
        if "los" in names and self.weighting:
            out.append({"params": list(self.los.parameters()), "name": "los"})
        if "nlos_gain" in names:
            out.append({"params": [self.nlos_gain_db], "name": "nlos_gain"})
        return out


@dataclass
class LinkTerms:
    """Per-link terms that do not depend on learned parameters.

    amp [M, G] float32: geometric amplitude * V_l * Tbar_l; lobe [M, G] float32: (1 + cos psi) / 2;
    phase [M, G] complex64: exp(-j k (d_l + r_l)); dist_m [M]; los_v [M] direct-path transmittance;
    freq_hz: the frequency.
    """

    amp: torch.Tensor
    lobe: torch.Tensor
    phase: torch.Tensor
    dist_m: torch.Tensor
    los_v: torch.Tensor
    freq_hz: float

    @property
    def num(self) -> int:
        return int(self.dist_m.shape[0])

    def subset(self, idx: torch.Tensor) -> "LinkTerms":
        return LinkTerms(self.amp[idx], self.lobe[idx], self.phase[idx], self.dist_m[idx], self.los_v[idx],
                         self.freq_hz)


def friis_los(dist_m: torch.Tensor, freq_hz: float) -> torch.Tensor:
    """Free-space direct path lambda / (4 pi d) exp(-j k d) [M] complex (isotropic antennas, P_T = 1 W)."""
    lam = C0 / freq_hz
    k = 2 * math.pi / lam
    return (lam / (4 * math.pi * dist_m)).to(torch.complex128) * torch.exp(-1j * k * dist_m.to(torch.float64))


def render_nlos(terms: LinkTerms, model: RssiModel) -> torch.Tensor:
    """S_NLoS [M] complex128 (without g_nlos): sum_l amp a_l lobe^R_l Gamma_l phase."""
    mats = model.rf.materials()
    lobe = terms.lobe.double() ** mats.roughness[None]
    weight = (terms.amp.double() * lobe * mats.opacity[None]).to(torch.complex128) * mats.gamma[None]
    return (weight * terms.phase.to(torch.complex128)).sum(-1)


def render_los(terms: LinkTerms, model: RssiModel) -> torch.Tensor:
    """Direct path [M] complex128: w(d, v) v Friis (or Friis alone without the weighting)."""
    friis = friis_los(terms.dist_m, terms.freq_hz)
    if not model.weighting:
        return friis
    h = model.los(torch.log(terms.dist_m), terms.los_v)
    return terms.los_v * torch.polar(torch.exp(h[:, 0]), h[:, 1]) * friis


def predict_db(terms: LinkTerms, model: RssiModel) -> torch.Tensor:
    """Predicted path gain [M] dB."""
    s = render_los(terms, model) + 10 ** (model.nlos_gain_db / 20) * render_nlos(terms, model)
    return 10 * torch.log10(s.abs() ** 2 + 1e-300) + model.rf.s_tx_db[0]


# ---------------------------------------------------------------------------------------------
# visibility: probe field (receivers), exact per Tx, direct-path segments
# ---------------------------------------------------------------------------------------------
@dataclass
class ProbeField:
    """Transmittance from lattice points to every Gaussian's mean: values [P, G] float32.

    Lattice: origin [3] m (first probe), step_m, shape (nx, ny, nz), probes x-major then y, then z.
    `at(points)` interpolates trilinearly (clamped to the lattice)."""

    origin: np.ndarray
    step_m: float
    shape: tuple
    values: torch.Tensor

    def points(self) -> torch.Tensor:
        axes = [self.origin[i] + self.step_m * np.arange(self.shape[i]) for i in range(3)]
        g = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        return torch.as_tensor(g, dtype=torch.float64)

    def at(self, points: torch.Tensor) -> torch.Tensor:
        """[N, G] float32 transmittances at points [N, 3] m."""
        shape = torch.as_tensor(self.shape)
        u = (points.double() - torch.as_tensor(self.origin)) / self.step_m
        u = torch.minimum(u.clamp(min=0.0), (shape - 1).double())
        i0 = torch.minimum(u.floor().long(), (shape - 2).clamp(min=0))
        f = (u - i0.double()).float()
        out = torch.zeros(len(points), self.values.shape[1], dtype=torch.float32)
        for corner in range(8):
            bits = torch.tensor([(corner >> b) & 1 for b in range(3)])
            idx = torch.minimum(i0 + bits, shape - 1)
            w = torch.prod(torch.where(bits.bool(), f, 1.0 - f), -1)
            flat = (idx[:, 0] * shape[1] + idx[:, 1]) * shape[2] + idx[:, 2]
            out += w[:, None] * self.values[flat]
        return out


def lattice_for(geom: FrozenGeometry, step_m: float) -> tuple[np.ndarray, tuple]:
    """Cell-centred lattice (origin, shape) covering the Gaussians' bounding box with `step_m`."""
    lo = geom.means.min(0).values.numpy()
    hi = geom.means.max(0).values.numpy()
    n = np.maximum(1, np.ceil((hi - lo) / step_m - 1e-9)).astype(int)
    origin = 0.5 * (lo + hi) - 0.5 * step_m * (n - 1)
    return origin, tuple(int(x) for x in n)


def point_transmittance(provider: OcclusionProvider, geom: FrozenGeometry, points: torch.Tensor,
                        opacity: torch.Tensor, margin_m: float, t_stop: float, chunk_points: int = 64,
                        progress_task=None) -> torch.Tensor:
    """[N, G] transmittance from each point to each Gaussian's mean (the target excluded, occluders
    within margin_m of the target ignored), traced with RF opacities [G]."""
    g = geom.num
    out = torch.empty(len(points), g, dtype=torch.float32)
    for a in range(0, len(points), chunk_points):
        p = points[a:a + chunk_points].double()
        target = torch.arange(g).repeat(len(p))
        v = provider.segment_transmittance(p.repeat_interleave(g, 0), target, margin_m, opacity, t_stop)
        out[a:a + len(p)] = v.reshape(len(p), g).float()
        if progress_task is not None:
            progress_task.advance(len(p))
    return out


def build_probe_field(provider, geom: FrozenGeometry, step_m: float, opacity: torch.Tensor, margin_m: float,
                      t_stop: float, progress_task=None) -> ProbeField:
    origin, shape = lattice_for(geom, step_m)
    field = ProbeField(origin, float(step_m), shape, torch.zeros(0))
    field.values = point_transmittance(provider, geom, field.points(), opacity, margin_m, t_stop,
                                       progress_task=progress_task)
    return field


def los_transmittance(provider: OcclusionProvider, tx_m: torch.Tensor, rx_m: torch.Tensor, opacity: torch.Tensor,
                      margin_m: float = 0.0) -> torch.Tensor:
    """v [M]: product of (1 - min(a_m G_m, 0.99)) over the Gaussians on each Tx-Rx segment (hits with
    margin_m < t < d - margin_m), RF opacities [G]. Uses the provider's ray hit tables."""
    diff = (rx_m - tx_m).double()
    length = diff.norm(dim=-1).clamp(min=1e-12)
    hits = provider.ray_hits(tx_m.double().contiguous(), (diff / length[:, None]).contiguous())
    keep = (hits.t_m > margin_m) & (hits.t_m < length[hits.query] - margin_m)
    return product_from_hits(hits.select(keep), opacity.double())


class OmniGeometry:
    """Per-Gaussian constants for `omni_link_geometry` (float32): means, normals, the six entries of
    Sigma^-1 and pi sqrt(det Sigma)."""

    def __init__(self, geom: FrozenGeometry):
        cov = covariance(geom.log_scales, geom.rotations)
        inv = torch.linalg.inv(cov)
        self.mu64 = geom.means.double()
        self.mu = [geom.means[:, i].float() for i in range(3)]
        self.n = [geom.normals[:, i].float() for i in range(3)]
        self.inv = [inv[:, i, j].float() for i, j in ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))]
        self.area0 = (math.pi * torch.sqrt(torch.linalg.det(cov))).float()


def omni_link_geometry(og: OmniGeometry, tx_m: torch.Tensor, rx_m: torch.Tensor, antenna: AntennaPattern):
    """(amp, lobe_base, path_m), each [M, G] float32, equal to render.link_geometry for omni antennas
    (isotropic, or dipoles along +z) but computed component-wise in float32 (test: rtol 1e-4)."""
    t = [tx_m[:, i, None].float() for i in range(3)]
    r = [rx_m[:, i, None].float() for i in range(3)]
    u = [og.mu[i][None] - t[i] for i in range(3)]
    d = torch.sqrt(u[0] ** 2 + u[1] ** 2 + u[2] ** 2)
    u = [x / d for x in u]
    w = [r[i] - og.mu[i][None] for i in range(3)]
    rr = torch.sqrt(w[0] ** 2 + w[1] ** 2 + w[2] ** 2)
    w = [x / rr for x in w]
    un = u[0] * og.n[0] + u[1] * og.n[1] + u[2] * og.n[2]
    wn = w[0] * og.n[0] + w[1] * og.n[1] + w[2] * og.n[2]
    side = torch.where(un > 0, -1.0, 1.0)                       # two-sided: the normal faces the Tx
    cos_o = (wn * side).clamp(min=0.0)
    cos_psi = u[0] * w[0] + u[1] * w[1] + u[2] * w[2] - 2.0 * un * wn
    a = og.inv
    quad = a[0] * u[0] ** 2 + a[1] * u[1] ** 2 + a[2] * u[2] ** 2 + 2.0 * (a[3] * u[0] * u[1] + a[4] * u[0] * u[2]
                                                                          + a[5] * u[1] * u[2])
    area = og.area0 * torch.sqrt(quad)
    amp = torch.sqrt(area / (4 * math.pi)) / d * un.abs() * torch.sqrt(cos_o) / (math.sqrt(4 * math.pi) * rr)
    if antenna.kind == "dipole":   # 1.5 sin^2 about +z, toward u from the Tx and toward -w from the Rx
        amp = amp * torch.sqrt(1.5 * (1 - u[2] ** 2)) * torch.sqrt(1.5 * (1 - w[2] ** 2))
    elif antenna.kind != "isotropic":
        raise ValueError(f"omni_link_geometry takes isotropic or dipole antennas, not {antenna.kind!r}")
    return amp, ((1.0 + cos_psi) / 2.0).clamp(min=0.0), d + rr


def _path_m(og: OmniGeometry, tx_m: torch.Tensor, rx_m: torch.Tensor) -> torch.Tensor:
    """d_l + r_l [M, G] in float64 (for the phase)."""
    return torch.cdist(tx_m.double(), og.mu64) + torch.cdist(rx_m.double(), og.mu64)


def link_terms(geom: FrozenGeometry, tx_m: torch.Tensor, rx_m: torch.Tensor, freq_hz: float, v_tx: torch.Tensor,
               tx_index: torch.Tensor, tbar_rx: torch.Tensor, rx_index: torch.Tensor, los_v: torch.Tensor,
               antenna: AntennaPattern, chunk_links: int = 256) -> LinkTerms:
    """LinkTerms for links tx_m / rx_m [M, 3]. v_tx [T, G]: V_l from each distinct Tx, tx_index [M]
    its row per link; tbar_rx [R, G] and rx_index [M] likewise at the receivers; los_v [M].
    Antenna axes +z (omni; the dipole's axis)."""
    m, g = len(tx_m), geom.num
    amp = torch.empty(m, g, dtype=torch.float32)
    lobe = torch.empty(m, g, dtype=torch.float32)
    phase = torch.empty(m, g, dtype=torch.complex64)
    k = 2 * math.pi * freq_hz / C0
    og = OmniGeometry(geom)
    with torch.no_grad():
        for a in range(0, m, chunk_links):
            t, r = tx_m[a:a + chunk_links].double(), rx_m[a:a + chunk_links].double()
            am, lb, path = omni_link_geometry(og, t, r, antenna)
            amp[a:a + len(t)] = am * v_tx[tx_index[a:a + len(t)]] * tbar_rx[rx_index[a:a + len(t)]]
            lobe[a:a + len(t)] = lb
            # the phase in float64: k (d + r) reaches ~500 rad, float32 would lose ~1e-4 rad
            path64 = _path_m(og, t, r)
            phase[a:a + len(t)] = torch.polar(torch.ones_like(path64), -k * path64).to(torch.complex64)
    dist = (rx_m - tx_m).double().norm(dim=-1)
    return LinkTerms(amp, lobe, phase, dist, los_v.double(), float(freq_hz))
