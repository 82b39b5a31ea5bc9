"""Learnable RF attributes with parametrisations that keep each in range.

a = sigmoid(theta_a) in (0, 1); R = 1 + softplus(theta_R) >= 1; |Gamma| = sigmoid(theta_g) in
(0, 1); angle(Gamma) = theta_phi (free, wrapped when written). Per frequency k a system gain
s_tx_db[k] [dB] scales the received power: it is |S_tx(f)|^2 of docs/physics.md section 4.1, the
transmitted signal, learned because the model's absolute level depends on the Gaussian density
(docs/rf-model.md).

Optional incoherent term (docs/rf-model.md): D = sigmoid(theta_d) in (0, 1), R_d = 1 + exp(theta_rd).
coherent=False drops the coherent sum (Gamma = 0, not learned): the incoherent term alone.

Sharing: "gaussian" (one set per Gaussian), "label" (one per object label), "global" (one).
"""
from __future__ import annotations

import math

import torch
from torch import nn

from .render import Materials


def _logit(p: float) -> float:
    p = min(max(p, 1e-6), 1 - 1e-6)
    return math.log(p / (1 - p))


def _softplus_inv(y: float) -> float:
    return y + math.log(-math.expm1(-y)) if y < 30 else y


class RFParams(nn.Module):
    """Raw parameters [P] gathered to Gaussians by `index` [G] (P groups)."""

    def __init__(self, index: torch.Tensor, num_freqs: int, *, opacity: float = 0.9, roughness: float = 4.0,
                 gamma_abs: float = 0.5, gamma_phase_rad: float = 0.0, diffuse: float | None = None,
                 diffuse_roughness: float = 2.0, coherent: bool = True):
        super().__init__()
        if roughness < 1.0:
            raise ValueError(f"initial roughness must be >= 1, got {roughness}")
        if not coherent and diffuse is None:
            raise ValueError("a model without the coherent sum needs the diffuse term")
        self.coherent = bool(coherent)
        p = int(index.max()) + 1 if index.numel() else 0
        self.register_buffer("index", index.long())
        full = lambda v: nn.Parameter(torch.full((p,), float(v), dtype=torch.float64))  # noqa: E731
        self.theta_a = full(_logit(opacity))
        self.theta_r = full(_softplus_inv(max(roughness - 1.0, 1e-6)))
        self.theta_g = full(_logit(gamma_abs))
        self.theta_phi = full(gamma_phase_rad)
        self.s_tx_db = nn.Parameter(torch.zeros(num_freqs, dtype=torch.float64))
        # Optional incoherent term: D = sigmoid(theta_d), R_d = 1 + exp(theta_rd) (log scale: lobes
        # from broad to narrow within a few steps).
        self.has_diffuse = diffuse is not None
        self.theta_d = full(_logit(diffuse if diffuse is not None else 0.1))
        self.theta_rd = full(math.log(max(diffuse_roughness - 1.0, 1e-6)))

    @staticmethod
    def sharing_index(kind: str, num_gaussians: int, labels: torch.Tensor | None) -> torch.Tensor:
        """Group index [G] for "gaussian", "label" or "global" sharing."""
        if kind == "gaussian":
            return torch.arange(num_gaussians)
        if kind == "global":
            return torch.zeros(num_gaussians, dtype=torch.int64)
        if kind == "label":
            if labels is None:
                raise ValueError("sharing = 'label' needs gaussians/labels in the scene")
            return torch.unique(labels, return_inverse=True)[1]
        raise ValueError(f"sharing {kind!r} unknown (gaussian, label, global)")

    def materials(self) -> Materials:
        i = self.index
        gamma_abs = torch.sigmoid(self.theta_g)[i] if self.coherent else torch.zeros_like(self.theta_g[i])
        gamma = torch.polar(gamma_abs, self.theta_phi[i])
        diffuse = torch.sigmoid(self.theta_d)[i] if self.has_diffuse else None
        diffuse_r = 1.0 + torch.exp(self.theta_rd)[i] if self.has_diffuse else None
        return Materials(torch.sigmoid(self.theta_a)[i], 1.0 + nn.functional.softplus(self.theta_r)[i], gamma,
                         diffuse, diffuse_r)

    def groups(self, names: list[str]) -> list[dict]:
        """Optimiser groups for the named attributes (opacity, roughness, gamma_abs, gamma_phase, s_tx,
        diffuse, diffuse_roughness; the last two only count when the model has the diffuse term)."""
        table = {"opacity": self.theta_a, "roughness": self.theta_r, "gamma_abs": self.theta_g,
                 "gamma_phase": self.theta_phi, "s_tx": self.s_tx_db, "diffuse": self.theta_d,
                 "diffuse_roughness": self.theta_rd}
        unknown = set(names) - set(table)
        if unknown:
            raise ValueError(f"unknown learnable attribute(s) {sorted(unknown)} (known: {sorted(table)})")
        if not self.has_diffuse:
            names = [n for n in names if n not in ("diffuse", "diffuse_roughness")]
        if not self.coherent:
            names = [n for n in names if n not in ("gamma_abs", "gamma_phase")]
        for key, param in table.items():
            param.requires_grad_(key in names)
        return [{"params": [table[n]], "name": n} for n in names]
