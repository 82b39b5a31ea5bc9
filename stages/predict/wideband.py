"""Spectrum plots of a physical model fitted on a band (docs/guide/rcs-sweep.md).

A band fit is predicted by rfir_stages.model.predict like any physical model, which predicts its band when
no frequency is asked for (`band_default_freqs`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np


def is_band_fit(rf) -> bool:
    """True for a physical model fitted on a band (rf-fit on wideband measurements)."""
    return "band.num_freqs" in rf.free.get("model@attrs", {})


def spectrum_plots(folder: Path, aspect_rad, range_m, freqs_hz, pred_dbsm, meas_dbsm=None, split=None,
                   num: int = 4) -> list[Path]:
    """One PNG: predicted (and measured) RCS [dBsm] versus frequency at `num` aspects spread over the
    test rows (all rows without a split). pred_dbsm / meas_dbsm [L, K]."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = np.arange(len(aspect_rad)) if split is None or not np.any(split == 1) else np.flatnonzero(split == 1)
    pick = rows[np.linspace(0, len(rows) - 1, min(num, len(rows))).round().astype(int)]
    fig, axes = plt.subplots(len(pick), 1, figsize=(7.0, 2.2 * len(pick)), sharex=True, squeeze=False)
    f_ghz = np.asarray(freqs_hz) / 1e9
    for ax, r in zip(axes[:, 0], pick):
        if meas_dbsm is not None:
            ax.plot(f_ghz, meas_dbsm[r], "-", lw=1.0, color="tab:orange", label="measured")
        ax.plot(f_ghz, pred_dbsm[r], "-", lw=1.0, color="tab:blue", label="predicted")
        what = "" if split is None else {0: " (train)", 1: " (test)"}.get(int(split[r]), "")
        ax.set_title(f"aspect {np.degrees(aspect_rad[r]):.0f} deg, range {range_m[r]:g} m{what}", fontsize=9)
        ax.set_ylabel("RCS [dBsm]")
        ax.grid(alpha=0.3)
    axes[0, 0].legend(fontsize=8)
    axes[-1, 0].set_xlabel("frequency [GHz]")
    fig.tight_layout()
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "spectrum_vs_frequency.png"
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return [path]
