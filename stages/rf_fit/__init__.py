"""Stage `rf-fit`: the physical radio model (rfir_stages.model) fitted to measurements.

Modules: `stage` (run: RCS and wideband fits), `physical_stage` (material sharing candidates, their
fits and the artifact), `wideband_stage` (a band's settings), `rssi_fit` / `room_stage` (the room
model for RSSI), `result` (RfFitResult). Links, tracing settings, the occlusion providers, antenna patterns and
split protocols live in the model package (rfir_stages.model: links, link_set, occlusion, antenna_patterns,
split_protocols), which rf-fit, predict and diagnose all import.
"""
from __future__ import annotations


def __getattr__(name):  # lazy: keep `import rfir_stages.rf_fit` cheap
    if name in ("run", "RfFitResult"):
        from . import stage
        return getattr(stage, name)
    raise AttributeError(name)


__all__ = ["run", "RfFitResult"]
