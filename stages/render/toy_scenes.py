"""Tiny SceneSpec-compatible scenes for tests and quick checks (independent of rfir_stages.simulate)."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class SimpleObject:
    """Duck-types rfir_stages.simulate.scenes.SceneObject."""

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    visual: str = "noise"
    color: tuple = (0.6, 0.6, 0.6)
    label: int = 0
    radio_material: str = "concrete"
    texture: np.ndarray | None = None  # (H, W, 3) in [0, 1], mapped once over the object's extent


@dataclass
class SimpleScene:
    """Duck-types rfir_stages.simulate.scenes.SceneSpec."""

    name: str
    kind: str
    objects: list = field(default_factory=list)
    bounds: np.ndarray = field(default_factory=lambda: np.zeros((2, 3)))


def box_mesh(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned box: 8 vertices, 12 outward-facing triangles."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[hi[0] if i & 1 else lo[0], hi[1] if i & 2 else lo[1], hi[2] if i & 4 else lo[2]]
                  for i in range(8)])
    f = np.array([[0, 2, 1], [1, 2, 3], [4, 5, 6], [5, 7, 6], [0, 1, 4], [1, 5, 4],
                  [2, 6, 3], [3, 6, 7], [0, 4, 2], [2, 4, 6], [1, 3, 5], [3, 7, 5]], np.int32)
    return v, f


def octahedron_mesh(center, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """A small octahedron (a marker whose silhouette centroid projects to its centre)."""
    c = np.asarray(center, float)
    v = c + radius * np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    f = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]], np.int32)
    return v, f


def textured_object_scene(name: str = "blocks") -> SimpleScene:
    """A small object made of three textured boxes (about 0.3 m across), standing at the origin."""
    parts = [("base", (-0.15, -0.1, 0.0), (0.15, 0.1, 0.08), "wood", (0.7, 0.5, 0.3)),
             ("tower", (-0.12, -0.08, 0.08), (0.0, 0.05, 0.25), "brick", (0.7, 0.3, 0.25)),
             ("block", (0.02, -0.06, 0.08), (0.13, 0.08, 0.15), "tiles", (0.3, 0.5, 0.7))]
    objects = []
    for i, (part, lo, hi, visual, color) in enumerate(parts):
        v, f = box_mesh(lo, hi)
        objects.append(SimpleObject(part, v, f, visual, color, label=i))
    verts = np.concatenate([o.vertices for o in objects])
    return SimpleScene(name, "object", objects, np.stack([verts.min(0), verts.max(0)]))


def marker_scene(marker_center, marker_radius: float = 0.01) -> SimpleScene:
    """A dark box with one bright octahedron marker (for projection tests)."""
    v, f = box_mesh((-0.5, -0.5, -0.2), (0.5, 0.5, 0.0))
    mv, mf = octahedron_mesh(marker_center, marker_radius)
    # explicit flat textures: the largest contrast, untouched by the procedural texture look
    objects = [SimpleObject("floor", v, f, texture=np.full((8, 8, 3), 0.03, np.float32)),
               SimpleObject("marker", mv, mf, label=1, texture=np.ones((8, 8, 3), np.float32))]
    return SimpleScene("marker", "object", objects, np.array([[-0.5, -0.5, -0.2], [0.5, 0.5, 0.2]]))


def aruco_marker(marker_id: int, size_m: float, centre, yaw_deg: float = 0.0, dictionary: str = "DICT_4X4_50",
                 z_offset_m: float = 5e-4) -> SimpleObject:
    """A printed ArUco marker lying flat (facing +z) with a white quiet zone of one cell.

    size_m is the black square's side; at yaw 0 the printed top edge points to +y (the layout
    convention of rfir_stages.calibrate.markers).
    """
    import cv2

    dic = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, dictionary))
    cells = dic.markerSize + 2
    px = 40 * cells
    img = cv2.aruco.generateImageMarker(dic, marker_id, px)
    pad = px // cells
    img = cv2.copyMakeBorder(img, pad, pad, pad, pad, cv2.BORDER_CONSTANT, value=255)
    # the texture's first row lands at low v, i.e. at -y: flip so the printed top edge is at +y
    img = np.flipud(img)
    if yaw_deg % 90:
        raise ValueError("toy markers support yaw in multiples of 90 degrees (planar UVs are axis-aligned)")
    img = np.rot90(img, k=int(round(yaw_deg / 90.0)) % 4, axes=(1, 0))  # turns the print by +yaw about +z
    tex = np.repeat(np.ascontiguousarray(img)[..., None], 3, axis=2).astype(np.float32) / 255.0 * 0.9 + 0.02
    half = 0.5 * size_m * (cells + 2) / cells
    cx, cy, cz = (float(x) for x in centre)
    v = np.array([[cx - half, cy - half, cz + z_offset_m], [cx + half, cy - half, cz + z_offset_m],
                  [cx + half, cy + half, cz + z_offset_m], [cx - half, cy + half, cz + z_offset_m]])
    f = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    return SimpleObject(f"aruco_{marker_id}", v, f, "plastic", (0.9, 0.9, 0.9), texture=tex)

