"""Links and the tracing settings that rf-fit, predict and the physical model (rfir_stages.model) share.

A LinkSet is M links (transmitter, receiver, antenna axes) at K frequencies; RenderSettings are the
[rf_fit] keys that say how visibility is traced (docs/physics.md section 4.1): whether at all, with
which RF opacity per Gaussian, from which Gaussian response on, and when a ray stops.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch


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
class RenderSettings:
    """How visibility is traced (configs/rf_fit.toml documents each key).

    visibility: trace it (False: every surfel sees both antennas). visibility_opacity: the RF
    opacity of every Gaussian along the traced rays (rf_fit.opacity). alpha_min: smallest Gaussian
    response traced. t_stop: rays stop once their transmittance falls below it. colocated_tol_m [m]:
    Tx and Rx closer than this share one traced segment (monostatic radar).
    """

    visibility: bool = True
    visibility_opacity: float = 0.9
    alpha_min: float = 1e-3
    t_stop: float = 1e-4
    colocated_tol_m: float = 0.01
