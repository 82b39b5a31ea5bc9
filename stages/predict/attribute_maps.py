"""Rendered RF attribute maps (the paper's |Gamma|, angle(Gamma), R figure) through the Gaussian tracer.

A pinhole view from a point (the radar, or an antenna) toward the scene: each pixel's ray is
composited front to back through the Gaussians with their RF opacities (rfir_tracer), carrying
the per-Gaussian attributes as features, so each map shows what that antenna "sees": the
attribute of the Gaussians that dominate each direction, weighted as the renderer weights them.
Pixels whose accumulated weight is below `min_weight` are left blank (nothing there).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch


def pinhole_rays(eye_m: np.ndarray, target_m: np.ndarray, fov_deg: float, width: int, height: int
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """Unit ray directions [H, W, 3] of a pinhole at eye_m [3] looking at target_m [3] (z up) and the
    eye as origin [3]; fov_deg is the horizontal field of view."""
    eye, tgt = np.asarray(eye_m, float), np.asarray(target_m, float)
    fwd = tgt - eye
    fwd /= np.linalg.norm(fwd)
    up = np.array([0.0, 0.0, 1.0]) if abs(fwd[2]) < 0.95 else np.array([1.0, 0.0, 0.0])
    right = np.cross(fwd, up)
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    half = math.tan(math.radians(fov_deg) / 2)
    xs = (np.arange(width) + 0.5) / width * 2 - 1
    ys = 1 - (np.arange(height) + 0.5) / height * 2
    u, v = np.meshgrid(xs * half, ys * half * height / width)
    d = fwd[None, None] + u[..., None] * right + v[..., None] * up
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    return torch.as_tensor(eye), torch.as_tensor(d)


def render_attribute_maps(means, log_scales, rotations, rf_opacity, attributes: dict[str, np.ndarray],
                          eye_m, target_m, *, fov_deg: float | None = None, width: int = 200, height: int = 150,
                          min_weight: float = 0.05) -> dict[str, np.ndarray]:
    """Maps [height, width] (NaN where nothing is seen) of each attribute [G], composited with the RF
    opacities [G]. Names containing "angle" are angles in radians, composited as unit phasors.
    fov_deg defaults to the angle the Gaussians subtend from the eye plus 10 %, in both image directions."""
    import rfir_tracer

    t = lambda x: torch.as_tensor(np.asarray(x), dtype=torch.float64).contiguous()  # noqa: E731
    mu = t(means)
    if fov_deg is None:
        rel = mu.numpy() - np.asarray(eye_m, float)
        fwd = np.asarray(target_m, float) - np.asarray(eye_m, float)
        fwd /= np.linalg.norm(fwd)
        cosang = (rel @ fwd) / np.linalg.norm(rel, axis=1)
        theta = math.acos(float(np.clip(cosang.min(), -1, 1)))
        # the vertical half-extent is tan(fov / 2) * height / width: cover theta both ways, + 10 %
        half = 1.1 * math.tan(min(theta, math.radians(55))) * max(1.0, width / height)
        fov_deg = min(150.0, 2 * math.degrees(math.atan(half)))
    origin, dirs = pinhole_rays(eye_m, target_m, fov_deg, width, height)
    names = list(attributes)
    columns = []
    for n in names:  # angles are composited as unit phasors, then read back with atan2
        columns += [torch.cos(t(attributes[n])), torch.sin(t(attributes[n]))] if "angle" in n else [t(attributes[n])]
    feats = torch.stack(columns, -1)
    scene = rfir_tracer.GaussianScene(mu, t(log_scales), t(rotations), t(rf_opacity).clamp(0.0, 1.0))
    with torch.no_grad():
        out = rfir_tracer.trace(scene, origin.expand_as(dirs).contiguous(), dirs.contiguous(), features=feats)
    weight = (1.0 - out.transmittance).numpy()
    maps, k = {}, 0
    feat = out.features.numpy()
    for n in names:
        if "angle" in n:
            img = np.arctan2(feat[..., k + 1], feat[..., k])
            k += 2
        else:
            img = feat[..., k] / np.maximum(weight, 1e-12)
            k += 1
        img[weight < min_weight] = np.nan
        maps[n] = img
    return maps


def plot_attribute_maps(path: Path, maps: dict[str, np.ndarray], title: str) -> Path:
    """One PNG, one panel per map (viridis; angle maps in a cyclic colour map; |Gamma| and S on 0..1)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(maps), figsize=(3.6 * len(maps), 3.2))
    for ax, (name, img) in zip(np.atleast_1d(axes), maps.items()):
        cyclic = "angle" in name
        unit = name.startswith("|Gamma|") or name.startswith("scattering S")   # coefficients in [0, 1]
        lo, hi = (-math.pi, math.pi) if cyclic else (0.0, 1.0) if unit else (None, None)
        im = ax.imshow(img, cmap="twilight" if cyclic else "viridis", vmin=lo, vmax=hi)
        ax.set_title(name, fontsize=10)
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(im, ax=ax, shrink=0.8)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
