"""Validate an edit against the independent simulator (issue 9).

Given a fit of the unedited scene (rf.h5), the measurements of the unedited scene and the
measurements the simulator made of the edited scene (`rfir simulate ... --scene-edit ...`, same links),
apply the same edit with `rfir edit` and compare:

- unedited MAE: the fit against the unedited scene, on the fit's test rows;
- edited MAE: the edited fit against the edited scene, on the same rows (target: <= 1.5x unedited);
- "not edited" MAE: the unedited fit against the edited scene (what ignoring the edit would cost);
- the correlation (Pearson) over all links between the change rfir predicts (edited fit - fit) and
  the change the simulator shows (edited scene - scene), in dB, and its rank (Spearman) version,
  which a few single-aspect glints of +-30 dB (Sionna's geometric optics) cannot dominate.

    python scripts/edit_validate.py RF BEFORE.h5 AFTER.h5 --select S --op O [...] --name NAME
        [--results results/NAME.json] [--plots DIR] [--work DIR]
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
from scipy.stats import rankdata

from rfir_core.artifacts import read_artifact
from rfir_core.figures import pyplot, save_figure
from rfir_core.physics.closed_forms import rcs_from_path_gain
from rfir_stages.diagnose.apply import apply_recorded_effects
from rfir_stages.model.antenna_patterns import antenna_from_attrs, link_axes
from rfir_stages.model.radio_model import load_model

from .script import edits_from_options
from .stage import run as run_edit


def predict_measured(rf_path: Path, meas_path: Path):
    """(predicted [L], measured [L], test mask [L]) of every measured link at the first frequency the model
    predicts there, as `rfir predict` scores them (the fit's test rows; the effects diagnose recorded): RCS in
    dBsm for a model fitted on RCS, path gain in dB for one fitted on RSSI."""
    model = load_model(rf_path)
    meas = read_artifact(meas_path, "measurements")
    f_meas = np.asarray(meas["freq_hz"], np.float64)
    freqs = model.default_freqs(f_meas)[:1]
    col = int(np.argmin(np.abs(f_meas - freqs[0])))
    tx, rx = np.asarray(meas["tx_pos"], np.float64), np.asarray(meas["rx_pos"], np.float64)
    aspect, range_m = meas.get("aspect_rad"), meas.get("range_m")
    axes = link_axes(meas, str(meas_path)) if model.task == "rssi" else None    # each link's antenna axes (room model)
    pg = apply_recorded_effects(model.artifact, model.predict(tx, rx, freqs, axes=axes), tx, rx, freqs, aspect_rad=aspect,
                                range_m=range_m)[:, 0]
    split = model.training_split(meas)
    test = np.zeros(len(tx), bool) if split is None else split == 1
    if model.task == "rssi":
        return pg, np.asarray(meas["path_gain_db"], np.float64)[:, col], test
    g0 = antenna_from_attrs(model.artifact.free.get("model@attrs", {})).boresight_gain   # RCS: in dBsm
    rcs = 10 * np.log10(rcs_from_path_gain(10 ** (pg / 10), np.asarray(range_m, np.float64), freqs[0], g0, g0))
    return rcs, np.asarray(meas["rcs_dbsm"], np.float64)[:, col], test


def change_metrics(pred_before, pred_after, meas_before, meas_after, test) -> dict:
    """The validation figures (module docstring) from per-link dB arrays [L] and a test mask [L]."""
    d_pred, d_meas = pred_after - pred_before, meas_after - meas_before
    big = np.abs(d_meas) > 1.0
    out = {
        "unedited_mae_db": float(np.mean(np.abs(pred_before - meas_before)[test])),
        "edited_mae_db": float(np.mean(np.abs(pred_after - meas_after)[test])),
        "not_edited_mae_db": float(np.mean(np.abs(pred_before - meas_after)[test])),
        "unedited_mae_all_db": float(np.mean(np.abs(pred_before - meas_before))),
        "edited_mae_all_db": float(np.mean(np.abs(pred_after - meas_after))),
        "num_test": int(test.sum()), "num_links": int(len(test)),
        "simulated_change_mean_abs_db": float(np.mean(np.abs(d_meas))),
        "predicted_change_mean_abs_db": float(np.mean(np.abs(d_pred))),
        "links_changed_over_1db": int(big.sum()),
    }
    out["mae_ratio"] = out["edited_mae_db"] / out["unedited_mae_db"]
    out["change_correlation"] = _pearson(d_pred, d_meas)
    out["change_rank_correlation"] = _pearson(rankdata(d_pred), rankdata(d_meas))   # Spearman
    out["change_correlation_over_1db"] = _pearson(d_pred[big], d_meas[big]) if big.sum() > 2 else float("nan")
    return out


def _pearson(a: np.ndarray, b: np.ndarray) -> float:
    if a.std() == 0 or b.std() == 0:
        return float("nan")
    return float(np.corrcoef(a, b)[0, 1])


def _plot(path: Path, name: str, d_pred: np.ndarray, d_meas: np.ndarray, m: dict) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(5.2, 5))
    ax.scatter(d_meas, d_pred, s=4, alpha=0.4, lw=0)
    lim = float(max(1.0, np.abs(d_meas).max(), np.abs(d_pred).max()))
    ax.plot([-lim, lim], [-lim, lim], color="0.5", lw=0.8)
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_aspect("equal")
    ax.set_xlabel("simulated change [dB] (Sionna, edited - unedited scene)")
    ax.set_ylabel("predicted change [dB] (rfir, edited - unedited fit)")
    ax.grid(alpha=0.3)
    ax.set_title(f"{name}: r = {m['change_correlation']:.2f} (rank {m['change_rank_correlation']:.2f}); "
                 f"MAE {m['unedited_mae_db']:.2f} -> {m['edited_mae_db']:.2f} dB", fontsize=9)
    return save_figure(fig, path, dpi=110)


def validate(rf_path, before_path, after_path, selects: list[str], ops: list[str], name: str, work_dir,
             results_path=None, plots_dir=None) -> dict:
    """Run the validation; return the metrics dict (also written to results_path as JSON)."""
    t0 = time.time()
    work = Path(work_dir)
    work.mkdir(parents=True, exist_ok=True)
    rf = read_artifact(rf_path, "rf")
    task = "rssi" if str(rf.attrs.get("task", "")) == "rssi" else "rcs"
    edited = work / f"{name}_rf.h5"
    plot = Path(plots_dir) / f"{name}_edit.png" if plots_dir is not None else None
    map_tx = None
    if task == "rssi":
        tx = np.asarray(read_artifact(after_path, "measurements")["tx_pos"])
        map_tx = np.unique(tx, axis=0)[0]
    res = run_edit(rf_path, edited, edits_from_options(selects, ops, False), plot_path=plot, map_tx=map_tx)
    _check_same_links(before_path, after_path)
    pb, mb, test = predict_measured(Path(rf_path), Path(before_path))
    pa, ma, test_a = predict_measured(edited, Path(after_path))
    if not np.array_equal(test, test_a):
        raise ValueError("the test rows of the two predictions differ")
    metrics = change_metrics(pb, pa, mb, ma, test)
    out = {"name": name, "task": task, "rf": str(rf_path), "measurements_unedited": str(before_path),
           "measurements_edited": str(after_path),
           "scene_edits": str(read_artifact(after_path, "measurements").free.get("simulator@attrs", {})
                              .get("scene_edits", "")),
           "rfir_edits": [f"--select {s} --op {o}" for s, o in zip(selects, ops)],
           "gaussians_selected": [int(r["selected"]) for r in res.records],
           "target": "edited MAE <= 1.5 x unedited MAE; report the change correlation",
           "meets_target": bool(metrics["mae_ratio"] <= 1.5), **metrics, "wall_s": time.time() - t0}
    if plots_dir is not None:
        out["plots"] = [str(_plot(Path(plots_dir) / f"{name}_change.png", name, pa - pb, ma - mb, metrics))]
        out["plots"] += [str(p) for p in (res.plot, res.radio_plot) if p is not None]
    if results_path is not None:
        Path(results_path).parent.mkdir(parents=True, exist_ok=True)
        Path(results_path).write_text(json.dumps(out, indent=2) + "\n")
    return out


def _check_same_links(before_path, after_path) -> None:
    b, a = read_artifact(before_path, "measurements"), read_artifact(after_path, "measurements")
    for key in ("tx_pos", "rx_pos"):
        if np.asarray(b[key]).shape != np.asarray(a[key]).shape or not np.allclose(b[key], a[key]):
            raise ValueError(f"{after_path}: its {key} differ from {before_path}; simulate both with the same settings")
