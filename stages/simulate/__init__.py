"""Stage `simulate`: ground-truth data sets (meshes, photos, radio measurements) from Sionna RT.

Public entry points: `run(...)` (see `stage.py`), the scene builder `scenes.build_scene`, and the
horn/omni antenna patterns in rfir_core.physics.antennas (the fitter uses the same patterns).
"""
from __future__ import annotations

from .scenes import SceneObject, SceneSpec, build_scene, write_meshes

__all__ = ["SceneObject", "SceneSpec", "build_scene", "write_meshes", "run", "SimulateResult"]


def __getattr__(name):  # lazy: importing scenes must not import sionna
    if name in ("run", "SimulateResult"):
        from . import stage
        return getattr(stage, name)
    raise AttributeError(name)
