"""A top view (world x-y) of the calibrated cameras and the sparse points, as a PNG."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def plot_top_view(path: Path, world_from_camera: np.ndarray, points_xyz: np.ndarray, points_rgb: np.ndarray,
                  title: str, metric: bool, reference_centres: np.ndarray | None = None,
                  max_points: int = 30000, seed: int = 0) -> Path:
    """Write the PNG: points in their colours, cameras as dots with their viewing direction."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 7), dpi=110)
    if len(points_xyz):
        keep = np.arange(len(points_xyz))
        if len(keep) > max_points:
            keep = np.random.default_rng(seed).choice(keep, max_points, replace=False)
        ax.scatter(points_xyz[keep, 0], points_xyz[keep, 1], s=1.0, c=points_rgb[keep] / 255.0, linewidths=0)
    centres = world_from_camera[:, :3, 3]
    forward = world_from_camera[:, :3, 2]
    span = np.ptp(np.concatenate([centres, points_xyz]) if len(points_xyz) else centres, axis=0)[:2].max()
    arrow = 0.06 * (span if span > 0 else 1.0)
    ax.quiver(centres[:, 0], centres[:, 1], forward[:, 0], forward[:, 1], angles="xy", scale_units="xy",
              scale=1.0 / arrow, color="tab:red", width=0.003)
    ax.plot(centres[:, 0], centres[:, 1], "o", ms=3, color="tab:red", label=f"{len(centres)} cameras")
    if reference_centres is not None and len(reference_centres):
        ax.plot(reference_centres[:, 0], reference_centres[:, 1], "x", ms=5, color="k", label="references")
    unit = "m" if metric else "SfM units"
    ax.set_xlabel(f"x ({unit})")
    ax.set_ylabel(f"y ({unit})")
    ax.set_title(title, fontsize=10)
    ax.set_aspect("equal", adjustable="datalim")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path)
    plt.close(fig)
    return path
