"""Turning a SceneSpec into a Mitsuba 3 scene (llvm_ad_rgb) for the photo renderer.

Meshes are built in memory; every face gets planar UVs on its dominant axis plane in world units
(so the texture density is the same everywhere and nothing stretches), scaled by a per-scene tile
size and shifted by a per-object offset so identical objects do not look identical.

Mitsuba's cameras look along +z with +x to the left of the image and +y up; ours (OpenCV) have +x
right and +y down, so Mitsuba's to_world is our world_from_camera times diag(-1, -1, 1, 1).
"""
from __future__ import annotations

import contextlib
from dataclasses import dataclass

import numpy as np

from .textures import _stable_seed, make_texture

MITSUBA_VARIANT = "llvm_ad_rgb"
OPENCV_TO_MITSUBA = np.diag([-1.0, -1.0, 1.0, 1.0])


@contextlib.contextmanager
def mitsuba_variant(variant: str = MITSUBA_VARIANT):
    """Set Mitsuba's (process-global) variant for the block and restore the previous one after,
    so the renderer does not disturb other Mitsuba users in the process (Sionna RT)."""
    import mitsuba as mi

    previous = mi.variant()
    mi.set_variant(variant)
    try:
        yield mi
    finally:
        if previous is not None and previous != variant:
            mi.set_variant(previous)


@dataclass
class LightSetup:
    """Point lights (positions (L,3) m, intensity W/sr each) plus an ambient term that is added as
    `ambient * albedo` after rendering (a noise-free fill light), and the background colour."""

    positions: np.ndarray
    intensity: float
    ambient: float = 0.35
    background: tuple = (0.55, 0.6, 0.66)


def face_uvs(tri: np.ndarray, tile_m: float, offset: np.ndarray) -> np.ndarray:
    """Planar UVs (F, 3, 2) for triangles (F, 3, 3): project each face onto the axis plane its
    normal is closest to, in units of `tile_m`."""
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    axis = np.argmax(np.abs(normal), axis=1)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[axis]  # (F, 2): the two coordinates in the plane
    uv = np.take_along_axis(tri, keep[:, None, :].repeat(3, axis=1), axis=2)
    # a different offset per dominant axis so a wall and the floor do not show the same patch
    return uv / tile_m + offset[axis][:, None, :]


def build_mesh(mi, name: str, vertices: np.ndarray, faces: np.ndarray, tile_m: float, seed: int):
    """A flat-shaded mitsuba Mesh with per-face planar UVs (vertices are split per face)."""
    tri = np.asarray(vertices, np.float64)[np.asarray(faces, np.int64)]  # (F, 3, 3)
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    tri = tri[area > 1e-12]
    if len(tri) == 0:
        return None
    offset = np.random.default_rng(_stable_seed(name, seed)).uniform(0.0, 1.0, (3, 2))
    uv = face_uvs(tri, tile_m, offset)
    mesh = mi.Mesh(name, 3 * len(tri), len(tri), has_vertex_normals=False, has_vertex_texcoords=True)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(tri.reshape(-1).astype(np.float32))
    params["faces"] = mi.UInt32(np.arange(3 * len(tri), dtype=np.uint32))
    params["vertex_texcoords"] = mi.Float(uv.reshape(-1).astype(np.float32))
    params.update()
    return mesh


def default_lights(spec) -> LightSetup:
    """Lights for a scene: a grid under the ceiling for rooms, three lights above for objects."""
    lo, hi = np.asarray(spec.bounds[0], float), np.asarray(spec.bounds[1], float)
    center, ext = 0.5 * (lo + hi), hi - lo
    if spec.kind == "room":
        z = hi[2] - 0.3
        xs = lo[0] + ext[0] * np.array([0.25, 0.75])
        ys = lo[1] + ext[1] * np.array([0.25, 0.75])
        pos = np.array([[x, y, z] for x in xs for y in ys])
        reach = max(z - lo[2] - 0.8, 1.0)
        return LightSetup(pos, intensity=1.6 * reach ** 2, ambient=0.4)
    radius = 0.5 * float(np.linalg.norm(ext))
    d = 4.0 * max(radius, 1e-3)
    az = np.radians([30.0, 150.0, 270.0])
    el = np.radians([55.0, 40.0, 65.0])
    pos = center + d * np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
    return LightSetup(pos, intensity=1.0 * d ** 2, ambient=0.35)


def tile_size_m(spec) -> float:
    """World size of one texture tile: about 2 mm per texel in rooms, finer for small objects."""
    ext = np.asarray(spec.bounds[1], float) - np.asarray(spec.bounds[0], float)
    if spec.kind == "room":
        return 2.5
    return float(np.clip(0.8 * np.max(ext), 0.05, 2.5))


def build_scene(mi, spec, width: int, height: int, K: np.ndarray, spp: int, seed: int = 0,
                texture_px: int = 1024, lights: LightSetup | None = None):
    """A Mitsuba scene for `spec` with an AOV integrator (RGBA, albedo, ray distance).

    The sensor's field of view and principal point reproduce K exactly (square pixels).
    """
    lights = lights or default_lights(spec)
    tile = tile_size_m(spec)
    fx, cx, cy = K[0, 0], K[0, 2], K[1, 2]
    if abs(K[1, 1] - fx) > 1e-6 * fx:
        raise ValueError("the renderer needs square pixels (fx == fy)")
    if abs(cx - (width - 1) / 2) > 1e-6 or abs(cy - (height - 1) / 2) > 1e-6:
        raise ValueError("the renderer needs the principal point at the image centre")
    hfov = np.degrees(2 * np.arctan(0.5 * width / fx))
    bsdfs: dict = {}
    scene: dict = {
        "type": "scene",
        "integrator": {"type": "aov", "aovs": "albedo:albedo,dist:depth",
                       "integrator": {"type": "path", "max_depth": 2, "hide_emitters": True}},
        "sensor": {
            "type": "perspective", "fov": float(hfov), "fov_axis": "x",
            "near_clip": 0.01, "far_clip": 1000.0,
            "film": {"type": "hdrfilm", "width": int(width), "height": int(height), "pixel_format": "rgba",
                     "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": int(spp)},
        },
    }
    for i, pos in enumerate(lights.positions):
        scene[f"light_{i}"] = {"type": "point", "position": [float(v) for v in pos],
                               "intensity": {"type": "rgb", "value": float(lights.intensity)}}
    for i, obj in enumerate(spec.objects):
        visual = getattr(obj, "visual", "noise") or "noise"
        color = tuple(float(c) for c in getattr(obj, "color", (0.6, 0.6, 0.6)))
        key = (visual, color)
        if key not in bsdfs:
            tex = make_texture(visual, color, texture_px, seed)
            bsdfs[key] = mi.load_dict({"type": "diffuse", "reflectance": {
                "type": "bitmap", "bitmap": mi.Bitmap(tex), "raw": True,
                "filter_type": "bilinear", "wrap_mode": "repeat"}})
        mesh = build_mesh(mi, f"obj{i}_{obj.name}", obj.vertices, obj.faces, tile, seed)
        if mesh is None:
            continue
        mesh.set_bsdf(bsdfs[key])
        scene[f"obj{i}"] = mesh
    return mi.load_dict(scene), lights


def mitsuba_to_world(world_from_camera: np.ndarray) -> np.ndarray:
    """Mitsuba sensor to_world for an OpenCV world_from_camera."""
    return np.asarray(world_from_camera, np.float64) @ OPENCV_TO_MITSUBA


def ray_caster(mi, scene):
    """A RayDistance function over the Mitsuba scene (distance to the first surface, inf on a miss)."""

    def distance(origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        o = np.asarray(origins, np.float32)
        d = np.asarray(dirs, np.float32)
        d = d / np.linalg.norm(d, axis=1, keepdims=True)
        ray = mi.Ray3f(mi.Point3f(o[:, 0], o[:, 1], o[:, 2]), mi.Vector3f(d[:, 0], d[:, 1], d[:, 2]))
        si = scene.ray_intersect(ray)
        t = np.array(si.t, dtype=np.float64)
        t[~np.array(si.is_valid())] = np.inf
        return t

    return distance
