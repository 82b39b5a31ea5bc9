"""PNG plots of predicted (and measured) RCS versus aspect, and of RF attributes (matplotlib, Agg)."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def rcs_vs_aspect(path: Path, aspect_rad: np.ndarray, pred_dbsm: np.ndarray, meas_dbsm: np.ndarray | None,
                  split: np.ndarray | None, title: str, polar: bool) -> Path:
    """One curve of predicted RCS [dBsm] over aspect (sorted), measured test/train points when given."""
    plt = _plt()
    order = np.argsort(aspect_rad)
    fig = plt.figure(figsize=(6.5, 6.0 if polar else 4.0))
    ax = fig.add_subplot(111, projection="polar" if polar else None)
    x = aspect_rad[order] if polar else np.degrees(aspect_rad[order])
    if meas_dbsm is not None:
        m = meas_dbsm[order]
        if split is not None:
            s = split[order]
            ax.plot(x[s == 0], m[s == 0], ".", ms=3, color="0.6", label="measured (train)")
            ax.plot(x[s != 0], m[s != 0], ".", ms=3, color="tab:orange", label="measured (test)")
        else:
            ax.plot(x, m, ".", ms=3, color="tab:orange", label="measured")
    ax.plot(x, pred_dbsm[order], "-", lw=1.2, color="tab:blue", label="predicted")
    if polar:
        lo = np.nanmin(pred_dbsm if meas_dbsm is None else np.concatenate([pred_dbsm, meas_dbsm]))
        ax.set_rmin(np.floor(lo / 10) * 10)
    else:
        ax.set_xlabel("aspect [deg]")
        ax.set_ylabel("RCS [dBsm]")
        ax.set_xlim(0, 360)
        ax.grid(alpha=0.3)
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=8, loc="lower right" if not polar else "lower left")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def attribute_views(path: Path, means: np.ndarray, values: dict[str, np.ndarray], view_dir: np.ndarray) -> Path:
    """Gaussian centres seen along `view_dir` (orthographic, nearest drawn last), coloured by each
    attribute (e.g. |Gamma|, angle(Gamma), R) in one PNG with one panel per attribute."""
    plt = _plt()
    d = np.asarray(view_dir, float)
    d = d / np.linalg.norm(d)
    up = np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    right = np.cross(d, up)
    right /= np.linalg.norm(right)
    up = np.cross(right, d)
    depth = means @ d
    order = np.argsort(-depth)  # far first
    u, v = means[order] @ right, means[order] @ up
    fig, axes = plt.subplots(1, len(values), figsize=(4.2 * len(values), 4.0))
    for ax, (name, val) in zip(np.atleast_1d(axes), values.items()):
        sc = ax.scatter(u, v, c=np.asarray(val)[order], s=4, cmap="viridis")
        ax.set_aspect("equal")
        ax.set_title(name, fontsize=10)
        ax.set_xticks([])
        ax.set_yticks([])
        fig.colorbar(sc, ax=ax, shrink=0.8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
