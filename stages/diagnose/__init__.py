"""Stage `diagnose`: where a model and measurements disagree, which missing effect explains it, add it.

See docs/guide/diagnose.md. `run` is the entry point; rows, breakdown, effects and select hold the parts.
"""
from __future__ import annotations


def __getattr__(name):
    if name in ("run", "DiagnoseResult"):
        from . import stage
        return getattr(stage, name)
    raise AttributeError(name)


__all__ = ["run", "DiagnoseResult"]
