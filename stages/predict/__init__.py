"""Stage `predict`: radio quantities from a fitted `rf` artifact (RCS first; see rcs.py)."""
from __future__ import annotations


def __getattr__(name):
    if name in ("run_rcs", "PredictResult"):
        from . import rcs
        return getattr(rcs, name)
    raise AttributeError(name)


__all__ = ["run_rcs", "PredictResult"]
