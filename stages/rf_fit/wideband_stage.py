"""`rfir rf-fit` on a band (task "wideband" or rf_fit.wideband.enabled = true): the settings that
turn a band into a fit of the physical model (docs/physics.md section 7).

Frequency is an input of the physical model, so a band is a setting, not another model: the
materials are fitted on rf_fit.wideband.fit_freqs evenly spaced frequencies of the band and the
artifact records the band (model attributes band.*) that predict rcs evaluates by default.
"""
from __future__ import annotations

import numpy as np

from rfir_core.errors import ConfigError
from rfir_stages.model.band import fit_columns

from rfir_stages.model.links import pick_freqs


def is_wideband_request(task: str, config: dict) -> bool:
    """True when rf-fit fits a band (wideband measurements, or rf_fit.wideband.enabled = true)."""
    return task == "wideband" or bool((config.get("wideband") or {}).get("enabled", False))


def fit_freqs_setting(config: dict) -> int:
    """rf_fit.wideband.fit_freqs, checked (a whole number >= 2: a band's fit needs both edges)."""
    value = (config.get("wideband") or {}).get("fit_freqs", 64)
    if not isinstance(value, int) or isinstance(value, bool) or value < 2:
        raise ConfigError(f"rf_fit.wideband.fit_freqs = {value!r}: expected a whole number >= 2")
    return value


def band_config(config: dict, meas, where: str, progress) -> tuple[dict, dict]:
    """(the [rf_fit] table for the physical model on the band, the band's model attributes).

    The band is every measured frequency, or rf_fit.freqs_hz; the materials are fitted on
    rf_fit.wideband.fit_freqs evenly spaced frequencies of it (rfir_stages.model.band.fit_columns);
    prediction evaluates any frequency. The residual is defined per fitted frequency, so a band fit
    has none (said when one was asked for)."""
    num_fit = fit_freqs_setting(config)
    f_all = np.asarray(meas["freq_hz"], np.float64)
    band = f_all[pick_freqs(f_all, config.get("freqs_hz"), where)]
    fit = band[fit_columns(len(band), num_fit)]
    phys = dict(config.get("physical") or {})
    if str(phys.get("residual", "auto")) != "off":
        progress.log(f"rf-fit (wideband): rf_fit.physical.residual = {phys.get('residual', 'auto')!r} not used: the "
                     "residual is defined per fitted frequency; the band is fitted by the physical model alone")
    progress.log(f"rf-fit (wideband): physical model on {len(band)} frequencies ({band.min() / 1e9:.4f}-"
                 f"{band.max() / 1e9:.4f} GHz); materials fitted on {len(fit)} of them, evenly spaced "
                 "(rf_fit.wideband.fit_freqs); predict evaluates every frequency")
    attrs = {"band.f_min_hz": float(band.min()), "band.f_max_hz": float(band.max()), "band.num_freqs": int(len(band)),
             "band.fit_freqs": int(len(fit))}
    return dict(config, freqs_hz=[float(x) for x in fit], physical=dict(phys, residual="off")), attrs
