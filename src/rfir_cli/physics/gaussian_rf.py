"""The per-Gaussian radio terms of the RFIR forward model (docs/physics.md sections 4-5, steps 1-5), in torch.

Shapes: G Gaussians, M links (Tx/Rx pairs), K frequencies. Positions in metres, world frame.
These are pure functions; the renderer (rf-fit) combines them with tracer visibilities.
"""
from __future__ import annotations

import math

import torch

from .closed_forms import C0


def quaternion_to_matrix(quat_wxyz: torch.Tensor) -> torch.Tensor:
    """[..., 4] (w, x, y, z), normalised inside -> rotation matrices [..., 3, 3]."""
    q = quat_wxyz / quat_wxyz.norm(dim=-1, keepdim=True)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(q.shape[:-1] + (3, 3))


def covariance(log_scales: torch.Tensor, quat_wxyz: torch.Tensor) -> torch.Tensor:
    """Sigma = R S S^T R^T from log standard deviations [G, 3] [log m] and quaternions [G, 4] -> [G, 3, 3] [m^2]."""
    rot = quaternion_to_matrix(quat_wxyz)
    scaled = rot * torch.exp(log_scales)[..., None, :]
    return scaled @ scaled.transpose(-1, -2)


def projected_cross_section_m2(cov_m2: torch.Tensor, direction: torch.Tensor) -> torch.Tensor:
    """A = pi sqrt(det Sigma) sqrt(u^T Sigma^-1 u): the Gaussian's area seen along unit `direction`.

    cov_m2: [G, 3, 3]; direction: [..., G, 3] unit vectors -> [..., G] in m^2 (pi s^2 for a sphere of std s).
    Uses the scales directly would be cheaper, but this form is exact for any covariance.
    """
    inv = torch.linalg.inv(cov_m2)
    quad = torch.einsum("...gi,gij,...gj->...g", direction, inv, direction)
    return math.pi * torch.sqrt(torch.linalg.det(cov_m2)) * torch.sqrt(quad)


def scattering_lobe(cos_theta_o: torch.Tensor, cos_psi: torch.Tensor, roughness: torch.Tensor) -> torch.Tensor:
    """F = sqrt(cos theta_o) ((1 + cos psi) / 2)^R, R >= 1; zero behind the surface."""
    return torch.sqrt(cos_theta_o.clamp(min=0.0)) * ((1.0 + cos_psi) / 2.0).clamp(min=0.0) ** roughness


def reflect(direction_in: torch.Tensor, normal: torch.Tensor) -> torch.Tensor:
    """Mirror direction of a ray travelling along `direction_in` off a surface with unit `normal`."""
    return direction_in - 2.0 * (direction_in * normal).sum(-1, keepdim=True) * normal


def bistatic_gaussian_response(means_m, cov_m2, normals, tx_m, rx_m, freq_hz, roughness, gamma, *,
                               tx_gain=None, rx_gain=None, visibility=None, rx_transmittance=None,
                               rf_opacity=None):
    """Complex contribution c_l of every Gaussian to every link and frequency (docs/physics.md sections 4-5, steps 1-3).

    means_m [G, 3], cov_m2 [G, 3, 3], normals [G, 3] (unit), tx_m / rx_m [M, 3], freq_hz [K],
    roughness [G] (>= 1), gamma [G] complex. Optional per-link-per-Gaussian factors [M, G]:
    tx_gain (power gain G_T toward the Gaussian), rx_gain (power gain C_R^2 toward the Gaussian),
    visibility (V_l from Tx), rx_transmittance (Tbar_l toward Rx); rf_opacity [G] (a_l).
    Returns [M, G, K] complex with P_T = 1 W: S = sum over G gives the received amplitude.

    Two-sided surfels: the normal is flipped to the Tx side; if the Rx is on the other side the
    contribution is zero (no transmission in the base model).
    """
    to_g = means_m[None] - tx_m[:, None]                      # [M, G, 3] Tx -> Gaussian
    d_in = to_g.norm(dim=-1)
    u_in = to_g / d_in[..., None]
    to_rx = rx_m[:, None] - means_m[None]                     # [M, G, 3] Gaussian -> Rx
    r_out = to_rx.norm(dim=-1)
    w_o = to_rx / r_out[..., None]
    n = normals[None].expand_as(u_in)
    side = torch.sign(-(u_in * n).sum(-1, keepdim=True))
    n = n * torch.where(side == 0, torch.ones_like(side), side)   # face the transmitter
    cos_i = -(u_in * n).sum(-1)
    cos_o = (w_o * n).sum(-1)
    cos_psi = (w_o * reflect(u_in, n)).sum(-1)
    lobe = scattering_lobe(cos_o, cos_psi, roughness[None]) * (cos_o > 0)
    area = projected_cross_section_m2(cov_m2, u_in)
    amp_in = torch.sqrt(area / (4 * math.pi * d_in**2))
    if tx_gain is not None:
        amp_in = amp_in * torch.sqrt(tx_gain)
    if visibility is not None:
        amp_in = amp_in * visibility
    amp = amp_in * lobe * cos_i.clamp(min=0) / (math.sqrt(4 * math.pi) * r_out)
    if rx_gain is not None:
        amp = amp * torch.sqrt(rx_gain)
    if rx_transmittance is not None:
        amp = amp * rx_transmittance
    if rf_opacity is not None:
        amp = amp * rf_opacity[None]
    k = 2 * math.pi * freq_hz / C0                           # [K]
    phase = torch.exp(-1j * k[None, None] * (d_in + r_out)[..., None])
    return (gamma[None, :, None] * amp[..., None]) * phase
