"""Adaptive density control: grow Gaussians where the photos pull hardest, drop the useless ones.

Between densification steps the trainer accumulates, per Gaussian, the norm of the gradient of
the loss w.r.t. its mean (world space, m^-1) over the steps in which it received one. At each
densification step:
- candidates are the Gaussians whose average gradient norm lies in the top `grow_fraction` of those
  that received any gradient (a relative rule: it needs no threshold in units of the scene), as
  long as the total stays under `max_gaussians`;
- a candidate larger than `split_scale` (its largest standard deviation, m) is split in two: two
  new Gaussians drawn inside it, standard deviations divided by 1.6, and the original removed;
- a smaller candidate is cloned: a copy drawn inside it at half its size offset, same shape;
- then Gaussians with opacity below `min_opacity`, or larger than `max_scale` (m), are pruned.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

from .model import GaussianModel, sample_inside


@dataclass
class DensifyStats:
    """Running sums per Gaussian: grad_sum [N] (sum of |dL/dmu|), count [N] (steps with a gradient)."""

    grad_sum: torch.Tensor
    count: torch.Tensor

    @classmethod
    def zeros(cls, n: int, device="cpu") -> "DensifyStats":
        return cls(torch.zeros(n, device=device), torch.zeros(n, device=device))

    def add(self, mean_grad: torch.Tensor) -> None:
        norm = mean_grad.detach().norm(dim=-1)
        self.grad_sum += norm
        self.count += (norm > 0).float()


@dataclass
class DensifyReport:
    cloned: int
    split: int
    pruned: int
    total: int


@torch.no_grad()
def densify_and_prune(model: GaussianModel, stats: DensifyStats, *, grow_fraction: float, max_gaussians: int,
                      split_scale: float, min_opacity: float, max_scale: float, generator: torch.Generator,
                      grow: bool = True) -> DensifyReport:
    """Apply one densification step in place (see the module docstring); returns the counts."""
    p = model.params
    n = model.num
    seen = stats.count > 0
    avg = torch.where(seen, stats.grad_sum / stats.count.clamp_min(1), torch.zeros_like(stats.grad_sum))
    cloned = split = 0
    grown = torch.zeros(n, dtype=torch.bool, device=avg.device)
    room = max(0, max_gaussians - n)
    if grow and room > 0 and int(seen.sum()) > 0 and grow_fraction > 0:
        k = min(int(round(grow_fraction * int(seen.sum()))), room)
        if k > 0:
            top = torch.topk(torch.where(seen, avg, torch.full_like(avg, -1.0)), k).indices
            grown[top] = True
            grown &= avg > 0
    max_s = torch.exp(p["log_scales"]).max(-1).values
    to_split = grown & (max_s > split_scale)
    to_clone = grown & ~to_split
    new_parts = []
    if int(to_clone.sum()):
        idx = torch.nonzero(to_clone).squeeze(1)
        part = {k: v.detach()[idx].clone() for k, v in p.items()}
        part["means"] = sample_inside(part["means"], part["log_scales"], part["rotations"], generator, spread=0.5)
        new_parts.append(part)
        cloned = len(idx)
    if int(to_split.sum()):
        idx = torch.nonzero(to_split).squeeze(1)
        for _ in range(2):
            part = {k: v.detach()[idx].clone() for k, v in p.items()}
            part["means"] = sample_inside(part["means"], part["log_scales"], part["rotations"], generator)
            part["log_scales"] = part["log_scales"] - torch.log(torch.tensor(1.6))
            new_parts.append(part)
        split = len(idx)
    keep = ~to_split
    opac = model.opacities().detach()
    keep &= opac >= min_opacity
    keep &= max_s <= max_scale
    pruned = int((~keep).sum()) - split
    model.keep(keep)
    for part in new_parts:
        model.append(part)
    return DensifyReport(cloned, split, pruned, model.num)
