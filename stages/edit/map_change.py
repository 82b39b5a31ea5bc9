"""The change an edit makes to the radio map (issue 9's before/after picture, radio half).

For an RSSI model: the map for one transmitter on a floor grid, predicted from the input and from
the edited artifact, and their difference in dB (after - before), as one PNG with three panels.
For an RCS model: RCS versus aspect at one range, before and after, in one PNG.
Both at one frequency: the one asked for (the room model predicts inside its material laws' range, the object
model anywhere), or the model's first fitted one.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rfir_core.figures import pyplot, save_figure


def rssi_map_change(path: Path, rf_before, rf_after, tx_m, height_m: float = 1.0, step_m: float = 0.4,
                    freq_hz: float | None = None) -> dict:
    """Predict the map of Tx tx_m [3] m at receivers on a grid (height_m, step_m over the input's floor
    plan) with both artifacts (or RadioModels already loaded) at freq_hz Hz (None: the model's fitted frequency);
    write the PNG; return {"mean_abs_change_db", "max_abs_change_db", "points", "freq_hz",
    "before_db" [P], "after_db" [P] (path gain at the points), "rx_m" [P, 3]}."""
    from rfir_stages.predict.rssi_checks import floor_grid
    from rfir_stages.model.radio_model import RadioModel, load_model

    loaded = lambda m: m if isinstance(m, RadioModel) else load_model(m, quantity="rssi")  # noqa: E731
    before, after = loaded(rf_before), loaded(rf_after)
    freq = float(before.default_freqs()[0]) if freq_hz is None else float(freq_hz)
    bounds = before.geometry.means.min(0).values.numpy(), before.geometry.means.max(0).values.numpy()
    rx = floor_grid(bounds, height_m, step_m)
    tx = np.broadcast_to(np.asarray(tx_m, np.float64).reshape(1, 3), rx.shape)
    pg0, pg1 = before.predict(tx, rx, [freq])[:, 0], after.predict(tx, rx, [freq])[:, 0]
    change = pg1 - pg0
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.8))
    lo, hi = float(min(pg0.min(), pg1.min())), float(max(pg0.max(), pg1.max()))
    lim = max(1e-3, float(np.abs(change).max()))
    panels = ((pg0, "before [dB]", "viridis", lo, hi), (pg1, "after [dB]", "viridis", lo, hi),
              (change, "change after - before [dB]", "RdBu_r", -lim, lim))
    for ax, (val, name, cmap, vmin, vmax) in zip(axes, panels):
        sc = ax.scatter(rx[:, 0], rx[:, 1], c=val, s=60, marker="s", cmap=cmap, vmin=vmin, vmax=vmax, lw=0)
        ax.plot([tx_m[0]], [tx_m[1]], marker="*", ms=15, color="red", mec="k")
        for art, colour in ((before, "0.6"), (after, "k")):
            m = art.geometry.means.numpy()
            ax.scatter(m[:, 0], m[:, 1], s=0.5, c=colour, alpha=0.3, lw=0)
        ax.set_aspect("equal")
        ax.set_title(name, fontsize=10)
        ax.set_xlabel("x [m]")
        fig.colorbar(sc, ax=ax, shrink=0.8)
    axes[0].set_ylabel("y [m]")
    fig.suptitle(f"radio map of the Tx at ({tx_m[0]:.2f}, {tx_m[1]:.2f}, {tx_m[2]:.2f}) m, receivers at "
                 f"{height_m:g} m, {freq / 1e9:g} GHz: mean |change| {np.mean(np.abs(change)):.2f} dB", fontsize=10)
    save_figure(fig, path, dpi=100)
    return {"mean_abs_change_db": float(np.mean(np.abs(change))), "max_abs_change_db": float(np.abs(change).max()),
            "points": int(len(rx)), "freq_hz": freq, "before_db": pg0, "after_db": pg1, "rx_m": rx}


def rcs_change(path: Path, rf_before, rf_after, range_m: float = 3.0, step_deg: float = 1.0,
               freq_hz: float | None = None) -> dict:
    """RCS [dBsm] versus aspect at range_m, before and after, at freq_hz Hz (None: the first fitted frequency)."""
    from rfir_core.physics.closed_forms import rcs_from_path_gain
    from rfir_stages.predict.rcs import predict_path_gain_db
    from rfir_stages.model.antenna_patterns import antenna_from_attrs
    from rfir_stages.model.links import geometry_from_artifact, radar_links, scene_centre

    centre = scene_centre(geometry_from_artifact(rf_before)).numpy()   # the same radar for both
    aspects = np.radians(np.arange(0.0, 360.0, step_deg))
    tx, rx, asp, rng = radar_links(aspects, np.array([range_m]), centre)
    freq = np.asarray(rf_before["rf/freq_hz"], np.float64)[:1] if freq_hz is None else np.array([float(freq_hz)])
    g0 = antenna_from_attrs(rf_before.free.get("model@attrs", {})).boresight_gain
    out = []
    for rf in (rf_before, rf_after):
        pg = predict_path_gain_db(rf, tx, rx, freq, "rcs")[:, 0]
        out.append(10 * np.log10(rcs_from_path_gain(10 ** (pg / 10), rng, freq[0], g0, g0)))
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7, 4))
    deg = np.degrees(asp)
    ax.plot(deg, out[0], color="0.5", lw=1.2, label="before")
    ax.plot(deg, out[1], color="tab:red", lw=1.2, label="after")
    ax.set_xlabel("aspect [deg]")
    ax.set_ylabel("RCS [dBsm]")
    ax.set_xlim(0, 360)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    change = out[1] - out[0]
    ax.set_title(f"RCS at {freq[0] / 1e9:g} GHz, {range_m:g} m: mean |change| {np.mean(np.abs(change)):.2f} dB",
                 fontsize=10)
    save_figure(fig, path, dpi=110)
    return {"mean_abs_change_db": float(np.mean(np.abs(change))), "max_abs_change_db": float(np.abs(change).max()),
            "points": int(len(asp)), "range_m": range_m, "aspect_step_deg": step_deg, "freq_hz": float(freq[0])}
