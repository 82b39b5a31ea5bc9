"""Tables over the incidence angle: nodes evenly spaced from 0 to 90 degrees, linear interpolation between them.

The fast evaluators of the radio model tabulate a material's Fresnel coefficients (or |Gamma|^2) on such nodes
once per material and frequency, and read each interaction's value between its two nearest nodes; how many
nodes is each evaluator's choice (its accuracy against the exact coefficients is tested there).
"""
from __future__ import annotations

import numpy as np
import torch


class AngleNodes:
    """`count` nodes theta_j = j * 90 / (count - 1) degrees, j = 0 .. count - 1."""

    def __init__(self, count: int):
        if int(count) < 2:
            raise ValueError(f"an angle table needs at least 2 nodes, got {count}")
        self.count = int(count)
        self.step_deg = 90.0 / (self.count - 1)

    def degrees(self) -> torch.Tensor:
        """[count] float64: theta_j [deg], j * step exactly, so that tables of node counts whose steps divide each
        other share their common nodes bit for bit."""
        return torch.arange(self.count, dtype=torch.float64) * self.step_deg

    def cosines(self) -> torch.Tensor:
        """[count] float64: cos(theta_j), the incidence cosines at which a table is evaluated."""
        return torch.cos(torch.deg2rad(self.degrees()))

    def _pos(self, cos_theta):
        if isinstance(cos_theta, torch.Tensor):
            return torch.rad2deg(torch.arccos(cos_theta.clamp(0.0, 1.0))) / self.step_deg
        return np.degrees(np.arccos(np.clip(cos_theta, 0.0, 1.0))) / self.step_deg

    def position(self, cos_theta):
        """(lower node j [...] int64 in [0, count - 2], weight of node j + 1 [...] in [0, 1]) of incidence cosines
        cos_theta [...] (torch or numpy, clipped to [0, 1]): the value there is (1 - w) table[j] + w table[j + 1]."""
        pos = self._pos(cos_theta)
        if isinstance(pos, torch.Tensor):
            lower = pos.floor().long().clamp(0, self.count - 2)
            return lower, (pos - lower).clamp(0.0, 1.0)
        lower = np.clip(np.floor(pos).astype(np.int64), 0, self.count - 2)
        return lower, np.clip(pos - lower, 0.0, 1.0)

    def nearest(self, cos_theta):
        """[...] int64: the node nearest to each incidence cosine (torch or numpy, clipped to [0, 1])."""
        pos = self._pos(cos_theta)
        if isinstance(pos, torch.Tensor):
            return pos.round().long().clamp(0, self.count - 1)
        return np.clip(np.rint(pos).astype(np.int64), 0, self.count - 1)
