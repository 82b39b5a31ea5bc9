"""Input validation with clear ValueErrors (the C++ side only guards raw pointers)."""
from __future__ import annotations

import math

import torch

ALPHA_MAX = 0.99  # alpha = min(opacity * G, 0.99), docs/physics.md section 2


def check_matrix(t: torch.Tensor, name: str, cols: int, rows: int | None = None) -> None:
    if not isinstance(t, torch.Tensor):
        raise ValueError(f"{name} must be a torch.Tensor, got {type(t).__name__}")
    if t.dim() != 2 or t.shape[1] != cols:
        raise ValueError(f"{name} must have shape [N, {cols}], got {list(t.shape)}")
    if rows is not None and t.shape[0] != rows:
        raise ValueError(f"{name} has {t.shape[0]} rows, expected {rows} (one per Gaussian)")


def check_finite(t: torch.Tensor, name: str) -> None:
    if t.numel() and not bool(torch.isfinite(t).all()):
        bad = int((~torch.isfinite(t)).sum())
        raise ValueError(f"{name} contains {bad} non-finite value(s) (NaN or inf)")


def check_float(t: torch.Tensor, name: str) -> None:
    if t.dtype not in (torch.float32, torch.float64):
        raise ValueError(f"{name} must be float32 or float64, got {t.dtype}")


def check_geometry(means, log_scales, rotations) -> None:
    check_matrix(means, "means", 3)
    n = means.shape[0]
    check_float(means, "means")
    check_matrix(log_scales, "log_scales", 3, n)
    check_matrix(rotations, "rotations", 4, n)
    for t, name in ((means, "means"), (log_scales, "log_scales"), (rotations, "rotations")):
        if t.device != means.device:
            raise ValueError(f"{name} is on {t.device} but means are on {means.device}")
        check_finite(t, name)
    if n and bool((rotations.detach().abs().sum(dim=1) == 0).any()):
        raise ValueError("rotations contains an all-zero quaternion (cannot be normalised)")


def check_opacities(opacities: torch.Tensor, n: int, name: str = "opacities") -> None:
    if not isinstance(opacities, torch.Tensor) or opacities.shape != (n,):
        shape = list(opacities.shape) if isinstance(opacities, torch.Tensor) else type(opacities).__name__
        raise ValueError(f"{name} must have shape [{n}], got {shape}")
    check_finite(opacities, name)
    if n and bool(((opacities < 0) | (opacities > 1)).any()):
        raise ValueError(f"{name} must lie in [0, 1] (apply the sigmoid before tracing)")


def check_params(alpha_min: float, t_stop: float) -> None:
    if not (0.0 < alpha_min < 1.0):
        raise ValueError(f"alpha_min must be in (0, 1), got {alpha_min}")
    if not (0.0 <= t_stop < 1.0):
        raise ValueError(f"t_stop must be in [0, 1), got {t_stop}")


def kappa2(alpha_min: float) -> float:
    """Squared Mahalanobis radius beyond which opacity * G < alpha_min for any opacity <= 1.

    A small slack keeps the bound conservative under rounding; the exact alpha test decides.
    """
    return 2.0 * math.log(1.0 / alpha_min) + 1e-6


def prepare_rays(origins, directions, t_min, t_max, dtype, device):
    """Flatten rays to [R, 3] / [R]; returns (o, d, t_min, t_max, batch_shape)."""
    if not isinstance(directions, torch.Tensor) or directions.dim() < 1 or directions.shape[-1] != 3:
        raise ValueError("directions must be a tensor of shape [..., 3]")
    batch = directions.shape[:-1]
    if not isinstance(origins, torch.Tensor) or origins.shape[-1:] != (3,):
        raise ValueError("origins must be a tensor of shape [3] or [..., 3]")
    try:
        o = torch.broadcast_to(origins.detach().to(device, dtype), batch + (3,))
    except RuntimeError:
        raise ValueError(
            f"origins of shape {list(origins.shape)} do not broadcast to rays {list(batch)}") from None
    d = directions.detach().to(device, dtype).reshape(-1, 3).contiguous()
    o = o.reshape(-1, 3).contiguous()
    check_finite(o, "origins")
    check_finite(d, "directions")
    if d.numel() and bool((d.abs().sum(dim=1) == 0).any()):
        raise ValueError("directions contains a zero vector")
    lims = []
    for v, name in ((t_min, "t_min"), (t_max, "t_max")):
        v = torch.as_tensor(v, dtype=dtype, device=device)
        if bool(torch.isnan(v).any()):
            raise ValueError(f"{name} contains NaN")
        try:
            lims.append(torch.broadcast_to(v.detach(), batch).reshape(-1).contiguous())
        except RuntimeError:
            raise ValueError(f"{name} of shape {list(v.shape)} does not broadcast to rays {list(batch)}") from None
    return o, d, lims[0], lims[1], batch
