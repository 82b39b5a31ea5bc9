"""Stage `geom`: 3D Gaussians with normals (the photo-based fitter is not here yet).

`from_mesh` tiles a triangle mesh with flat Gaussians (surfels): a geometry oracle for rf-fit.
"""
from __future__ import annotations

from .from_mesh import gaussians_from_mesh, scene_from_mesh, write_scene_artifact

__all__ = ["gaussians_from_mesh", "scene_from_mesh", "write_scene_artifact"]
