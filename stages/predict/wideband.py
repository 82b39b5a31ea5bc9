"""Prediction with a wideband `rf` artifact (docs/physics.md section 7) and spectrum plots.

A physical model fitted on a band (docs/wideband.md) is predicted by rfir_stages.model.predict like
any physical model; `default_freqs` gives its band when no frequency is asked for.
A free wideband artifact (rf-fit on a "wideband" measurement file; stages/rf_fit/wideband_stage.py)
holds the base materials, the system gain s_tx(f) as knots and the modulation network in its free
group model/ (`wideband.*` datasets and attributes). It predicts any frequency inside the fitted
band [wideband.f_min_hz, wideband.f_max_hz] (each with its own k) and refuses others.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from rfir_cli.errors import SchemaError, StageError
from rfir_cli.progress import NullProgress
from rfir_stages.rf_fit.antennas import AntennaPattern
from rfir_stages.rf_fit.links import geometry_from_artifact, make_links, scene_centre
from rfir_stages.rf_fit.occlusion import make_provider
from rfir_stages.rf_fit.render import RenderSettings, build_cache
from rfir_stages.rf_fit.wideband import WidebandModel, load_flat_state, pairs_from_cache
from rfir_stages.rf_fit.wideband_stage import STATE_PREFIX

BAND_TOL = 1e-9  # relative tolerance on the band edges


def is_wideband_model(rf) -> bool:
    """True for an rf artifact written by the wideband fit."""
    return bool(int(rf.free.get("model@attrs", {}).get("wideband", 0)))


def is_band_fit(rf) -> bool:
    """True for a physical model fitted on a band (rf-fit on wideband measurements, docs/wideband.md)."""
    return "band.num_freqs" in rf.free.get("model@attrs", {})


def default_freqs(rf, measured_hz=None) -> np.ndarray:
    """Frequencies [K] Hz predicted when none are asked for: a band fit's whole band (the measured
    frequencies inside it, or its num_freqs evenly spaced without measurements); otherwise the fitted ones."""
    if not is_band_fit(rf):
        return np.asarray(rf["rf/freq_hz"], np.float64)
    attrs = rf.free["model@attrs"]
    lo, hi = float(attrs["band.f_min_hz"]), float(attrs["band.f_max_hz"])
    if measured_hz is None:
        return np.linspace(lo, hi, int(attrs["band.num_freqs"]))
    f = np.asarray(measured_hz, np.float64)
    return f[(f >= lo * (1 - BAND_TOL)) & (f <= hi * (1 + BAND_TOL))]


def band_hz(rf) -> tuple[float, float]:
    attrs = rf.free.get("model@attrs", {})
    return float(attrs["wideband.f_min_hz"]), float(attrs["wideband.f_max_hz"])


def check_band(rf, freqs_hz, where: str = "") -> None:
    """One-line StageError for a frequency outside the fitted band."""
    lo, hi = band_hz(rf)
    f = np.asarray(freqs_hz, np.float64)
    bad = f[(f < lo * (1 - BAND_TOL)) | (f > hi * (1 + BAND_TOL))]
    if bad.size:
        raise StageError(f"{bad[0] / 1e9:.6g} GHz is outside the fitted wideband range {lo / 1e9:.6g}-{hi / 1e9:.6g} GHz"
                         f" ({bad.size} such frequencies); predict inside the band or fit a wider one", path=where or None)


def load_wideband(rf, network: bool | None = None) -> tuple[WidebandModel, AntennaPattern, RenderSettings]:
    """The model (network on when the artifact was fitted with it, or as `network` says), antenna and
    renderer settings recorded by rf-fit."""
    attrs = rf.free.get("model@attrs", {})
    flat = {k[len(STATE_PREFIX):]: v for k, v in rf.free.get("model", {}).items() if k.startswith(STATE_PREFIX)}
    if "base.index" not in flat or "s_tx.knots_db" not in flat:
        raise SchemaError("wideband model without its model/wideband.* datasets (damaged or not from rf-fit)",
                          path=rf.path)
    lo, hi = band_hz(rf)
    net = {k: int(attrs[f"wideband.{k}"]) for k in ("embed_dim", "hidden", "layers", "fourier")}
    index = torch.as_tensor(np.asarray(flat["base.index"], np.int64))
    model = WidebandModel(index, lo, hi, knots=len(flat["s_tx.knots_db"]), net=net)
    try:
        load_flat_state(model, flat)
    except RuntimeError as exc:
        raise SchemaError(f"wideband model does not match its settings: {str(exc).splitlines()[0]}",
                          path=rf.path) from None
    model.use_network = bool(int(attrs.get("wideband.network", 1))) if network is None else bool(network)
    ant = AntennaPattern(str(attrs.get("antenna_kind", "isotropic")), hpbw_deg=float(attrs.get("antenna_hpbw_deg", 40.0)))
    kw = {}
    for f in RenderSettings.__dataclass_fields__:
        if f"render.{f}" in attrs:
            v = attrs[f"render.{f}"]
            kw[f] = bool(v) if isinstance(RenderSettings.__dataclass_fields__[f].default, bool) else float(v)
    return model, ant, RenderSettings(**kw)


def predict_wideband_db(rf, tx, rx, freqs, task: str, *, occlusion: str = "auto", chunk_links: int = 64,
                        freq_chunk: int = 32, progress=None, render_overrides: dict | None = None,
                        network: bool | None = None, single: bool = True) -> np.ndarray:
    """Path gain [L, K] dB for links tx/rx [L, 3] m at freqs [K] Hz (inside the fitted band).

    single: render in float32 (about 2x faster; < 0.01 dB from float64 where the path gain is within
    60 dB of its link's strongest contribution)."""
    progress = progress or NullProgress()
    freqs = np.asarray(freqs, np.float64)
    check_band(rf, freqs, str(rf.path))
    model, ant, settings = load_wideband(rf, network)
    for key, value in (render_overrides or {}).items():
        setattr(settings, key, value)
    settings.learn_visibility = False
    geom = geometry_from_artifact(rf)
    centre = scene_centre(geom)
    provider = make_provider(occlusion, geom, settings.alpha_min) if settings.visibility else None
    floor = float(rf.free.get("model@attrs", {}).get("wideband.pair_floor", 0.0))
    f_t = torch.as_tensor(freqs)
    out = np.zeros((len(tx), len(freqs)))
    with progress.task("predict (wideband)", total=len(tx)) as bar, torch.no_grad():
        for a in range(0, len(tx), chunk_links):
            links = make_links(tx[a:a + chunk_links], rx[a:a + chunk_links], freqs[:1], centre, task)
            pairs = pairs_from_cache(build_cache(geom, links, ant, ant, provider, settings), floor)
            pairs = pairs.to(torch.float32) if single else pairs
            for b in range(0, len(freqs), freq_chunk):
                out[a:a + chunk_links, b:b + freq_chunk] = model.predict_db(pairs, f_t[b:b + freq_chunk]).numpy()
            bar.advance(links.num)
    return out


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
