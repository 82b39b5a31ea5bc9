"""Stage `geom`: 3D Gaussians with normals.

- `stage.run` (`rfir geom`): Gaussians with learnable normals trained on calibrated photos through
  the ext/ tracer (modules data, init, model, render, losses, densify, train, evaluate, tsdf,
  export_ply; docs/guide/photos-to-scene.md).
- `from_mesh` (`rfir mesh-gaussians`): a triangle mesh tiled with flat Gaussians (surfels), a
  geometry oracle for rf-fit and tests.
"""
from __future__ import annotations

from .from_mesh import gaussians_from_mesh, scene_from_mesh, write_scene_artifact

__all__ = ["gaussians_from_mesh", "scene_from_mesh", "write_scene_artifact"]
