"""Stage `edit`: select Gaussians of an `rf` artifact and move, rotate, delete, duplicate or re-material them.

See docs/guide/edit.md. `run` is the stage entry point; selection.py and operations.py hold the pure parts.
"""
from __future__ import annotations


def __getattr__(name):
    if name in ("run", "EditResult"):
        from . import stage
        return getattr(stage, name)
    raise AttributeError(name)


__all__ = ["run", "EditResult"]
