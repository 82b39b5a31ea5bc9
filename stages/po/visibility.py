"""Lit/shadow tests by ray casting (Open3D RaycastingScene, Embree on the CPU).

A facet sample point is visible from a position when the segment from the point (pushed off the
surface by a small offset along the facet normal, on the side being tested) to that position
hits no triangle of the scene. Far-field sources use a ray to infinity along the direction.
"""
from __future__ import annotations

import numpy as np


class Occluder:
    """Ray-casting scene over a triangle mesh (float32 inside Open3D)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, max_rays: int = 1 << 20):
        import open3d as o3d

        self._o3c = o3d.core
        self.scene = o3d.t.geometry.RaycastingScene()
        self.scene.add_triangles(o3d.core.Tensor(np.ascontiguousarray(vertices, np.float32)),
                                 o3d.core.Tensor(np.ascontiguousarray(faces, np.uint32)))
        v = np.asarray(vertices, float)
        self.size = float(np.linalg.norm(v.max(0) - v.min(0))) if len(v) else 1.0
        self.max_rays = int(max_rays)

    def _rays(self, origins, directions):
        r = np.concatenate([origins, directions], axis=1).astype(np.float32)
        return self._o3c.Tensor(np.ascontiguousarray(r))

    def unoccluded(self, origins: np.ndarray, directions: np.ndarray, tfar: float = np.inf) -> np.ndarray:
        """True where the ray origin + t * direction, 0 < t < tfar, hits nothing.

        For a segment to a point P pass direction = P - origin and tfar slightly below 1.
        """
        n = len(origins)
        out = np.empty(n, dtype=bool)
        for s in range(0, n, self.max_rays):
            e = min(n, s + self.max_rays)
            occ = self.scene.test_occlusions(self._rays(origins[s:e], directions[s:e]), tnear=0.0, tfar=float(tfar))
            out[s:e] = ~occ.numpy().astype(bool)
        return out

    def first_hit(self, origins: np.ndarray, directions: np.ndarray):
        """(t_hit (N,), primitive id (N,) int64, -1 where nothing is hit)."""
        n = len(origins)
        t = np.empty(n)
        pid = np.empty(n, dtype=np.int64)
        for s in range(0, n, self.max_rays):
            e = min(n, s + self.max_rays)
            ans = self.scene.cast_rays(self._rays(origins[s:e], directions[s:e]))
            t[s:e] = ans["t_hit"].numpy()
            p = ans["primitive_ids"].numpy().astype(np.int64)
            p[~np.isfinite(t[s:e])] = -1
            pid[s:e] = p
        return t, pid
