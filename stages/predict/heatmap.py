"""PNG figures of `predict rssi`: radio maps over the floor plan, and the RF attributes seen from an antenna.

- `radio_map`: values at receiver points [N, 3] drawn over the floor plan (the Gaussians' centres
  projected on the x-y plane, grey), the transmitter marked with a star. Points on a regular x-y
  grid are drawn as cells (pcolormesh), others as coloured squares.
- `fov_maps`: the paper's appendix figure: |Gamma|, angle(Gamma) [deg] and R rendered from an
  antenna position over its field of view (omni: 180 x 360 degrees, equirectangular), composited
  front to back with the RF opacities by rfir_tracer (features / (1 - T)), plus the RF depth.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _as_grid(points: np.ndarray, values: np.ndarray):
    """(xs, ys, V [ny, nx]) when the points fill a regular x-y grid, else None."""
    xs, ys = np.unique(np.round(points[:, 0], 6)), np.unique(np.round(points[:, 1], 6))
    if len(xs) * len(ys) != len(points) or len(xs) < 2 or len(ys) < 2:
        return None
    grid = np.full((len(ys), len(xs)), np.nan)
    ix = np.searchsorted(xs, np.round(points[:, 0], 6))
    iy = np.searchsorted(ys, np.round(points[:, 1], 6))
    grid[iy, ix] = values
    return xs, ys, grid


def _edges(c: np.ndarray) -> np.ndarray:
    mid = 0.5 * (c[1:] + c[:-1])
    return np.concatenate([[c[0] - (mid[0] - c[0])], mid, [c[-1] + (c[-1] - mid[-1])]])


def radio_map(path: Path, points: np.ndarray, values: np.ndarray, tx: np.ndarray, floor_xy: np.ndarray, title: str,
              label: str, cmap: str = "viridis", vmin=None, vmax=None) -> Path:
    """One heatmap PNG. points [N, 3] m, values [N], tx [3] m, floor_xy [G, 2] m (Gaussian centres)."""
    plt = _plt()
    fig, ax = plt.subplots(figsize=(7.0, 5.6))
    ax.scatter(floor_xy[:, 0], floor_xy[:, 1], s=1, c="0.35", alpha=0.4, zorder=3, lw=0)
    grid = _as_grid(points, values)
    if grid is not None:
        xs, ys, v = grid
        im = ax.pcolormesh(_edges(xs), _edges(ys), v, cmap=cmap, vmin=vmin, vmax=vmax, zorder=2, alpha=0.9)
    else:
        im = ax.scatter(points[:, 0], points[:, 1], c=values, s=30, marker="s", cmap=cmap, vmin=vmin, vmax=vmax,
                        zorder=2)
    ax.plot([tx[0]], [tx[1]], marker="*", ms=16, color="red", mec="k", zorder=4, label=f"Tx at z = {tx[2]:.2f} m")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper right", fontsize=8)
    fig.colorbar(im, ax=ax, shrink=0.8, label=label)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def render_fov(geom, opacity: np.ndarray, features: np.ndarray, origin: np.ndarray, step_deg: float = 2.0,
               alpha_min: float = 1e-3):
    """Equirectangular render from origin [3] m: (maps [n_el, n_az, K], depth [n_el, n_az] m, elevation
    and azimuth cell centres [deg]). features [G, K] are composited with RF opacities [G]
    (rfir_tracer) and divided by the accumulated alpha (1 - T) so each map shows attribute values."""
    import rfir_tracer

    el = np.arange(90.0 - step_deg / 2, -90.0, -step_deg)
    az = np.arange(-180.0 + step_deg / 2, 180.0, step_deg)
    e, a = np.meshgrid(np.radians(el), np.radians(az), indexing="ij")
    dirs = np.stack([np.cos(e) * np.cos(a), np.cos(e) * np.sin(a), np.sin(e)], -1).reshape(-1, 3)
    scene = rfir_tracer.GaussianScene(geom.means.contiguous(), geom.log_scales.contiguous(), geom.rotations.contiguous(),
                                      normals=geom.normals.contiguous())
    with torch.no_grad():
        out = rfir_tracer.trace(scene, torch.as_tensor(origin, dtype=torch.float64), torch.as_tensor(dirs),
                                opacities=torch.as_tensor(opacity, dtype=torch.float64),
                                features=torch.as_tensor(features, dtype=torch.float64), alpha_min=alpha_min)
    acc = (1.0 - out.transmittance).clamp(min=1e-6)[:, None]
    maps = (out.features / acc).numpy().reshape(len(el), len(az), -1)
    depth = (out.depth / acc[:, 0]).numpy().reshape(len(el), len(az))
    return maps, depth, el, az


def fov_maps(path: Path, geom, rf, origin: np.ndarray, step_deg: float = 2.0) -> Path:
    """PNG with |Gamma|, angle(Gamma) [deg], R and RF depth seen from origin (omni field of view)."""
    phase = np.asarray(rf["rf/gamma_phase_rad"], np.float64)
    feats = np.stack([np.asarray(rf["rf/gamma_abs"], np.float64), np.cos(phase), np.sin(phase),
                      np.asarray(rf["rf/roughness"], np.float64)], 1)
    maps, depth, el, az = render_fov(geom, np.asarray(rf["rf/opacity"], np.float64), feats, origin, step_deg)
    panels = {"|Gamma|": maps[..., 0], "angle(Gamma) [deg]": np.degrees(np.arctan2(maps[..., 2], maps[..., 1])),
              "roughness R": maps[..., 3], "RF depth [m]": depth}
    plt = _plt()
    fig, axes = plt.subplots(2, 2, figsize=(11, 6))
    extent = (az[0] - step_deg / 2, az[-1] + step_deg / 2, el[-1] - step_deg / 2, el[0] + step_deg / 2)
    for ax, (name, img) in zip(axes.ravel(), panels.items()):
        cmap = "twilight" if "angle" in name else "viridis"
        im = ax.imshow(img, extent=extent, aspect="auto", cmap=cmap)
        ax.set_title(f"{name} from ({', '.join(f'{x:.2f}' for x in origin)}) m", fontsize=9)
        ax.set_xlabel("azimuth [deg]")
        ax.set_ylabel("elevation [deg]")
        fig.colorbar(im, ax=ax, shrink=0.85)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def error_limits(err: np.ndarray) -> tuple[float, float]:
    """Symmetric colour limits for an error map (the 98th percentile of |error|, at least 1 dB)."""
    m = float(np.nanpercentile(np.abs(err), 98)) if np.isfinite(err).any() else 1.0
    m = max(m, 1.0)
    return -math.ceil(m), math.ceil(m)
