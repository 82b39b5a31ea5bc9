"""Surfels for rooms: fine on large surfaces (floor, ceiling, walls), coarse on small objects.

A room at the ~lambda/4 spacing the RCS objects use would need ~10^6 surfels. What the RSSI model
needs from large flat surfaces is the phase of their specular reflections: the path length
through a surfel's centre differs from the specular path by about delta^2 / 2 (1/d_1 + 1/d_2)
for a centre delta metres from the specular point, so 0.3 m cells keep that error near 0.3 rad
at 2.4 GHz and a few metres, while furniture (legs, seats) only needs to be present. Objects
whose bounding box is at least `large_m` across get `fine_m` spacing, the others `coarse_m`.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from rfir_cli.errors import ConfigError


def mixed_spacing_fields(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray, fine_m: float, coarse_m: float,
                         large_m: float = 2.0) -> tuple[dict, dict]:
    """Scene fields (rfir_stages.geom.gaussians_from_mesh) with per-object spacing, and
    {label: spacing_m}. vertices [V, 3] m, faces [F, 3], labels [F] (one object per label)."""
    from rfir_stages.geom import gaussians_from_mesh

    if not (fine_m > 0 and coarse_m > 0 and large_m > 0):
        raise ConfigError("spacings and large_m must be positive")
    parts, spacing = [], {}
    for lab in np.unique(labels):
        f = faces[labels == lab]
        v = vertices[np.unique(f)]
        s = fine_m if float(np.max(v.max(0) - v.min(0))) >= large_m else coarse_m
        spacing[int(lab)] = s
        parts.append(gaussians_from_mesh(vertices, f, s, labels=labels[labels == lab]))
    fields = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    return fields, spacing


def room_scene_artifact(mesh_path, out_path, fine_m: float = 0.3, coarse_m: float = 0.8, large_m: float = 2.0) -> Path:
    """Read a labelled PLY (as `rfir simulate` writes, labels.json beside it) and write a scene
    artifact with mixed spacing. Returns the path."""
    from rfir_stages.geom import write_scene_artifact
    from rfir_stages.geom.mesh_io import read_ply_mesh

    mesh = read_ply_mesh(mesh_path)
    labels = mesh.labels if mesh.labels is not None else np.zeros(len(mesh.faces), np.int64)
    fields, _ = mixed_spacing_fields(mesh.vertices, mesh.faces, labels, fine_m, coarse_m, large_m)
    top = int(labels.max()) + 1
    names = [mesh.label_names.get(i, f"label_{i}") for i in range(top)]
    return write_scene_artifact(out_path, fields, label_names=names, source=str(mesh_path),
                                spacing_m=f"{fine_m} (objects >= {large_m} m), {coarse_m} (others)")
