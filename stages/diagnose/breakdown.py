"""Where the model and the measurements disagree: the residual broken down by what an engineer can act on.

Each breakdown bins the rows by one feature (aspect, frequency, range or distance, predicted level,
elevation, LoS/NLoS, transmitter, receiver cell). Structure is tested on held-out rows, not read
off a plot: the bin means of the training residuals predict the test residuals; the held-out R^2
of that prediction is compared with the same R^2 after shuffling the bins of the training rows
(PERMUTATIONS times). A breakdown has structure when its R^2 > MIN_R2 and the permutation p < P_MAX.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rfir_core.figures import pyplot, save_figure

from .rows import Rows

PERMUTATIONS = 200
P_MAX = 0.01
MIN_R2 = 0.02
LARGE_R2 = 0.5   # a breakdown explaining this share of the held-out residual is structure a model lacks
AXIS = {"aspect": "aspect", "frequency": "frequency", "range": "range", "distance": "range (distance)",
        "predicted level": "predicted level", "elevation": "elevation", "transmitter": "transmitter",
        "receiver cell (1 m)": "receiver cell", "incidence angle": "incidence angle", "LoS / NLoS": "LoS / NLoS"}


@dataclass
class Breakdown:
    feature: str
    labels: list            # bin labels
    bins: np.ndarray        # [N] bin index per row
    mean_train: np.ndarray  # [B] mean residual per bin (train rows), nan where empty
    mean_test: np.ndarray
    count: np.ndarray       # [B] rows per bin
    r2_heldout: float
    p_value: float
    structure: bool
    worst_bin: str
    worst_mae_db: float


def _quantile_bins(values: np.ndarray, n: int, unit: str, fmt: str = "{:.3g}") -> tuple[np.ndarray, list]:
    edges = np.unique(np.quantile(values, np.linspace(0, 1, n + 1)))
    if len(edges) < 2:
        return np.zeros(len(values), int), [fmt.format(values[0]) + unit]
    idx = np.clip(np.searchsorted(edges, values, side="right") - 1, 0, len(edges) - 2)
    return idx, [f"{fmt.format(edges[i])}-{fmt.format(edges[i + 1])}{unit}" for i in range(len(edges) - 1)]


def features(rows: Rows) -> dict[str, tuple[np.ndarray, list]]:
    """feature name -> (bin index [N], bin labels)."""
    out = {}
    if rows.aspect_rad is not None:
        deg = np.degrees(np.mod(rows.aspect_rad, 2 * np.pi))
        idx = (deg // 10).astype(int)
        out["aspect"] = (idx, [f"{10 * i}-{10 * i + 10} deg" for i in range(36)])
    if len(np.unique(rows.freq_hz)) >= 4:
        out["frequency"] = _quantile_bins(rows.freq_hz / 1e9, 10, " GHz", "{:.4g}")
    if np.ptp(rows.dist_m) > 0.05 * np.median(rows.dist_m):
        out["range" if rows.monostatic else "distance"] = _quantile_bins(rows.dist_m, 8, " m")
    out["predicted level"] = _quantile_bins(rows.pred_db, 8, " dB", "{:.0f}")
    if not rows.monostatic:
        out["elevation"] = _quantile_bins(np.degrees(rows.elevation_rad()), 6, " deg", "{:.0f}")
        tx_ids = np.unique(np.round(rows.tx_m, 3), axis=0, return_inverse=True)[1].reshape(-1)
        if 2 <= tx_ids.max() + 1 <= 64:
            out["transmitter"] = (tx_ids, [f"Tx {i}" for i in range(tx_ids.max() + 1)])
        cell = np.floor(rows.rx_m[:, :2]).astype(int)
        cid = np.unique(cell, axis=0, return_inverse=True)[1].reshape(-1)
        if cid.max() + 1 >= 2:
            out["receiver cell (1 m)"] = (cid, [f"cell {i}" for i in range(cid.max() + 1)])
    if rows.incidence_deg is not None and np.isfinite(rows.incidence_deg).sum() > 0.5 * rows.num:
        inc = np.nan_to_num(rows.incidence_deg, nan=90.0)   # rays that hit nothing: grazing bin
        idx = np.minimum((inc // 10).astype(int), 8)
        out["incidence angle"] = (idx, [f"{10 * i}-{10 * i + 10} deg" for i in range(9)])
    if rows.crossings is not None:
        out["LoS / NLoS"] = ((rows.crossings > 0).astype(int), ["LoS", "NLoS"])
    return out


def _heldout_r2(r: np.ndarray, bins: np.ndarray, train: np.ndarray, test: np.ndarray, nb: int) -> float:
    mu = float(np.mean(r[train]))
    s = np.bincount(bins[train], weights=r[train], minlength=nb)
    c = np.bincount(bins[train], minlength=nb)
    means = np.where(c > 0, s / np.maximum(c, 1), mu)
    sse0 = float(np.sum((r[test] - mu) ** 2))
    sse1 = float(np.sum((r[test] - means[bins[test]]) ** 2))
    return 1.0 - sse1 / sse0 if sse0 > 0 else 0.0


def _bin_means(r: np.ndarray, bins: np.ndarray, mask: np.ndarray, nb: int) -> np.ndarray:
    """[nb] mean of r over the rows in mask per bin (nan where a bin has none)."""
    s = np.bincount(bins[mask], weights=r[mask], minlength=nb)
    c = np.bincount(bins[mask], minlength=nb)
    return np.where(c > 0, s / np.maximum(c, 1), np.nan)


def analyse(rows: Rows, base_db: np.ndarray, seed: int = 0) -> list[Breakdown]:
    """The breakdowns of measured - base_db (module docstring)."""
    r = rows.meas_db - base_db
    rng = np.random.default_rng(seed)
    out = []
    for name, (bins, labels) in features(rows).items():
        nb = len(labels)
        r2 = _heldout_r2(r, bins, rows.train, rows.test, nb)
        tr = np.flatnonzero(rows.train)
        null = np.empty(PERMUTATIONS)
        shuffled = bins.copy()
        for i in range(PERMUTATIONS):
            shuffled[tr] = bins[rng.permutation(tr)]
            null[i] = _heldout_r2(r, shuffled, rows.train, rows.test, nb)
        p = float((1 + np.sum(null >= r2)) / (1 + PERMUTATIONS))
        count = np.bincount(bins, minlength=nb)
        mae = np.array([np.mean(np.abs(r[bins == b])) if count[b] else 0.0 for b in range(nb)])
        worst = int(np.argmax(mae))
        out.append(Breakdown(name, labels, bins, _bin_means(r, bins, rows.train, nb), _bin_means(r, bins, rows.test, nb),
                             count, float(r2), p,
                             bool(r2 > MIN_R2 and p < P_MAX), labels[worst], float(mae[worst])))
    return out


def plot(path: Path, rows: Rows, residual_db: np.ndarray, items: list[Breakdown], title: str,
         boxes=()) -> Path:
    """One PNG: a panel per breakdown (mean residual per bin, train and test), plus a map of the mean
    residual [N] dB per receiver position for links, with the obstacle boxes (x0, y0, x1, y1 m) drawn."""
    plt = pyplot()
    panels = [b for b in items if b.feature != "receiver cell (1 m)"]
    has_map = not rows.monostatic
    n = len(panels) + has_map
    cols = min(3, n)
    nrows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(nrows, cols, figsize=(5.2 * cols, 3.6 * nrows), squeeze=False)
    for ax, b in zip(axes.flat, panels):
        x = np.arange(len(b.labels))
        ax.bar(x - 0.2, b.mean_train, 0.4, label="train", color="0.6")
        ax.bar(x + 0.2, b.mean_test, 0.4, label="test", color="tab:red")
        ax.axhline(0, color="k", lw=0.6)
        step = max(1, len(x) // 8)
        ax.set_xticks(x[::step])
        ax.set_xticklabels([b.labels[i] for i in x[::step]], rotation=30, ha="right", fontsize=7)
        ax.set_ylabel("mean residual [dB]")
        flag = "STRUCTURE" if b.structure else "no structure"
        ax.set_title(f"{b.feature}: held-out R2 {b.r2_heldout:.2f}, p {b.p_value:.3f} ({flag})", fontsize=8)
        ax.legend(fontsize=7)
    if has_map:
        ax = axes.flat[len(panels)]
        r = residual_db
        keys, inv = np.unique(np.round(rows.rx_m[:, :2], 2), axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        mean = np.bincount(inv, weights=r) / np.bincount(inv)
        lim = max(1e-3, float(np.quantile(np.abs(mean), 0.98)))
        sc = ax.scatter(keys[:, 0], keys[:, 1], c=mean, cmap="RdBu_r", vmin=-lim, vmax=lim, s=25, marker="s")
        txs = np.unique(np.round(rows.tx_m, 3), axis=0)
        ax.scatter(txs[:, 0], txs[:, 1], marker="*", s=60, c="k")
        for x0, y0, x1, y1 in boxes:
            ax.plot([x0, x1, x1, x0, x0], [y0, y0, y1, y1, y0], color="k", lw=1.5, ls="--")
            ax.annotate("obstacle", (x0, y1), fontsize=7, va="bottom")
        ax.set_aspect("equal")
        ax.set_title("mean residual per receiver position [dB] (Tx: stars)", fontsize=8)
        fig.colorbar(sc, ax=ax, shrink=0.8)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.suptitle(title, fontsize=10)
    return save_figure(fig, path, dpi=90)
