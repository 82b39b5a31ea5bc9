"""Stage `rf-fit`: per-Gaussian radio materials (RF opacity, roughness, complex Gamma) by inverse rendering.

Modules: `render` (the forward model, docs/physics.md sections 4-5), `occlusion` (hit tables from the
tracer or a brute-force oracle), `grid` (the receiver's direction grid), `antennas`, `params`
(parametrisations), `fit` (Adam, checkpoints), `links` (artifacts -> renderer inputs), `stage` (run).
"""
from __future__ import annotations


def __getattr__(name):  # lazy: keep `import rfir_stages.rf_fit` cheap
    if name in ("run", "RfFitResult"):
        from . import stage
        return getattr(stage, name)
    raise AttributeError(name)


__all__ = ["run", "RfFitResult"]
