"""Before/after top view (x-y) of the Gaussians with the edited ones highlighted."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rfir_core.figures import pyplot, save_figure


def top_view(path: Path, before_m: np.ndarray, selected: np.ndarray, after_m: np.ndarray, touched: np.ndarray,
             title: str = "") -> Path:
    """Write a PNG: left, input centres before_m [G, 3] m with selected [G] bool in colour; right, the
    edited centres after_m [G', 3] m with touched [G'] bool in colour. Axes equal, metres."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 5.2))
    both = np.concatenate([before_m[:, :2], after_m[:, :2]]) if len(after_m) else before_m[:, :2]
    lo, hi = both.min(0), both.max(0)
    pad = 0.05 * float(np.max(hi - lo)) + 1e-3
    for ax, pts, hot, name in ((axes[0], before_m, selected, "before (selection)"),
                               (axes[1], after_m, touched, "after (edited)")):
        size = max(1.0, 2000.0 / max(len(pts), 1))
        ax.scatter(pts[~hot, 0], pts[~hot, 1], s=size, c="0.7", lw=0, label="other")
        ax.scatter(pts[hot, 0], pts[hot, 1], s=size * 2, c="tab:red", lw=0, label=f"{int(hot.sum())} highlighted")
        ax.set_title(f"{name}: {len(pts)} Gaussians")
        ax.set_xlabel("x [m]")
        ax.set_xlim(lo[0] - pad, hi[0] + pad)
        ax.set_ylim(lo[1] - pad, hi[1] + pad)
        ax.set_aspect("equal", adjustable="box")
        ax.legend(loc="upper right", fontsize=8)
    axes[0].set_ylabel("y [m]")
    if title:
        fig.suptitle(title, fontsize=9)
    return save_figure(fig, path, dpi=110)
