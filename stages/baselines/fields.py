"""Pieces the neural-field baselines share (NeRF2-style and WRF-GS-style): ray directions,
positional encoding and plain MLPs."""
from __future__ import annotations

import math

import torch
from torch import nn


def fibonacci_sphere(n: int) -> torch.Tensor:
    """[n, 3] float64 unit vectors spread evenly over the sphere (Fibonacci lattice)."""
    i = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1 - 2 * i / n
    r = torch.sqrt(torch.clamp(1 - z * z, min=0))
    phi = math.pi * (3 - math.sqrt(5)) * i
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], 1)


def encode(x: torch.Tensor, n_freqs: int) -> torch.Tensor:
    """Positional encoding [.., D] -> [.., D (1 + 2 n_freqs)]: x, sin(2^k pi x), cos(2^k pi x)."""
    freqs = (2.0 ** torch.arange(n_freqs, dtype=x.dtype, device=x.device)) * math.pi
    xf = (x[..., None, :] * freqs[:, None]).flatten(-2)
    return torch.cat([x, torch.sin(xf), torch.cos(xf)], -1)


def mlp(n_in: int, width: int, layers: int, n_out: int) -> nn.Sequential:
    """`layers` hidden Linear + ReLU layers of `width`, then a Linear to n_out."""
    mods: list[nn.Module] = []
    d = n_in
    for _ in range(layers):
        mods += [nn.Linear(d, width), nn.ReLU()]
        d = width
    mods.append(nn.Linear(d, n_out))
    return nn.Sequential(*mods)


def decay_lr(opt: torch.optim.Optimizer, base_lrs: list[float], decay: float, step: int, total_steps: int,
             elapsed_s: float, budget_s: float | None) -> None:
    """Set each param group's lr to base * decay^frac, frac = the larger of the share of steps done and
    the share of the wall-clock budget used (capped at 1): the decay ends with whichever ends first."""
    frac = step / max(1, total_steps)
    if budget_s is not None:
        frac = max(frac, elapsed_s / budget_s)
    for group, lr0 in zip(opt.param_groups, base_lrs):
        group["lr"] = lr0 * decay ** min(frac, 1.0)
