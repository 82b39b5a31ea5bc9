"""Stage `rf-fit`: the physical radio model (rfir_stages.model) fitted to measurements.

Modules: `stage` (run: RCS and wideband fits), `physical_stage` (material sharing candidates, their
fits and the artifact), `wideband_stage` (a band's settings), `rssi_fit` / `room_stage` (the room
model for RSSI), `links` (artifacts -> links), `render` (LinkSet, tracing settings), `occlusion`
(the tracer or a brute-force oracle), `antennas`, `splits` (train/test protocols).
"""
from __future__ import annotations


def __getattr__(name):  # lazy: keep `import rfir_stages.rf_fit` cheap
    if name in ("run", "RfFitResult"):
        from . import stage
        return getattr(stage, name)
    raise AttributeError(name)


__all__ = ["run", "RfFitResult"]
