"""Turning a SceneSpec into a Mitsuba 3 scene (llvm_ad_rgb) for the photo renderer.

Meshes are built in memory; every face gets planar UVs on its dominant axis plane in world units
(so the texture density is the same everywhere and nothing stretches). Each object gets its own
texture, sized to cover it once, so no pattern repeats (repeats confuse structure from motion).

Mitsuba's cameras look along +z with +x to the left of the image and +y up; ours (OpenCV) have +x
right and +y down, so Mitsuba's to_world is our world_from_camera times diag(-1, -1, 1, 1).
"""
from __future__ import annotations

import contextlib
from dataclasses import dataclass, replace

import numpy as np

from .textures import stable_seed, make_texture

MITSUBA_VARIANT = "llvm_ad_rgb"
OPENCV_TO_MITSUBA = np.diag([-1.0, -1.0, 1.0, 1.0])
NEAR_CLIP_M = 0.01  # Mitsuba starts camera rays on the near plane; depth AOVs count from there


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


SELF_LIT_VISUALS = ("glass",)   # seen by their own light: a pane shows the daylight behind it


@dataclass
class LightSetup:
    """Point lights (positions (L,3) m, intensity W/sr each) plus an ambient term that is added as
    `ambient * albedo` after rendering (a noise-free fill light), and the background colour.
    self_lit_shapes: the scene's shape indices (the shape_index AOV's, from 1) whose pixels show their
    texture as it is, unshaded (SELF_LIT_VISUALS)."""

    positions: np.ndarray
    intensity: float
    ambient: float = 0.35
    background: tuple = (0.55, 0.6, 0.66)
    self_lit_shapes: tuple = ()


def face_uvs(tri: np.ndarray, origin: np.ndarray, tile_m: float) -> np.ndarray:
    """Planar UVs (F, 3, 2) for triangles (F, 3, 3): project each face onto the axis plane its
    normal is closest to, measured from `origin`, in units of `tile_m` (so [0, 1] spans a tile)."""
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    axis = np.argmax(np.abs(normal), axis=1)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[axis]  # (F, 2): the two coordinates in the plane
    uv = np.take_along_axis(tri - origin, keep[:, None, :].repeat(3, axis=1), axis=2)
    return uv / tile_m


def build_mesh(mi, name: str, tri: np.ndarray, origin: np.ndarray, tile_m: float):
    """A flat-shaded mitsuba Mesh from triangles (F,3,3) with planar UVs (vertices are split per face)."""
    mesh = mi.Mesh(name, 3 * len(tri), len(tri), has_vertex_normals=False, has_vertex_texcoords=True)
    params = mi.traverse(mesh)
    params["vertex_positions"] = mi.Float(tri.reshape(-1).astype(np.float32))
    params["faces"] = mi.UInt32(np.arange(3 * len(tri), dtype=np.uint32))
    params["vertex_texcoords"] = mi.Float(face_uvs(tri, origin, tile_m).reshape(-1).astype(np.float32))
    params.update()
    return mesh


def _triangles(obj) -> np.ndarray:
    tri = np.asarray(obj.vertices, np.float64)[np.asarray(obj.faces, np.int64)].reshape(-1, 3, 3)
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    return tri[area > 1e-12]


def default_lights(spec) -> LightSetup:
    """One point light (noise-free direct lighting with hard, view-independent shadows) plus the
    ambient fill: under the ceiling in the middle of a room, above and in front of an object."""
    lo, hi = np.asarray(spec.bounds[0], float), np.asarray(spec.bounds[1], float)
    center, ext = 0.5 * (lo + hi), hi - lo
    if spec.kind == "room":
        pos = np.array([[center[0], center[1], hi[2] - 0.3]])
        reach = max(hi[2] - lo[2] - 1.0, 1.0)
        return LightSetup(pos, intensity=1.2 * reach ** 2, ambient=0.45)
    radius = 0.5 * float(np.linalg.norm(ext))
    d = 4.0 * max(radius, 1e-3)
    az, el = np.radians(30.0), np.radians(55.0)
    pos = center + d * np.array([[np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]])
    return LightSetup(pos, intensity=1.2 * d ** 2, ambient=0.4)


def texel_size_m(spec) -> float:
    """World size of one texel: 4 mm in rooms, 1/1024 of the object's size for objects."""
    ext = np.asarray(spec.bounds[1], float) - np.asarray(spec.bounds[0], float)
    if spec.kind == "room":
        return 0.004
    return float(max(np.max(ext), 0.05) / 1024.0)


def build_scene(mi, spec, width: int, height: int, K: np.ndarray, spp: int, seed: int = 0,
                texture_px: int = 1024, lights: LightSetup | None = None, max_texture_px: int = 3072):
    """A Mitsuba scene for `spec` with an AOV integrator (RGBA, albedo, ray distance).

    Every object gets its own texture covering it once; texture_px sets the texel density (texels
    per texel_size_m(spec) * 1024 metres; 1024 is the reference). The sensor reproduces K exactly.
    """
    lights = lights or default_lights(spec)
    texel = texel_size_m(spec) * 1024.0 / texture_px
    fx, cx, cy = K[0, 0], K[0, 2], K[1, 2]
    if abs(K[1, 1] - fx) > 1e-6 * fx:
        raise ValueError("the renderer needs square pixels (fx == fy)")
    if abs(cx - (width - 1) / 2) > 1e-6 or abs(cy - (height - 1) / 2) > 1e-6:
        raise ValueError("the renderer needs the principal point at the image centre")
    hfov = np.degrees(2 * np.arctan(0.5 * width / fx))
    scene: dict = {
        "type": "scene",
        "integrator": {"type": "aov", "aovs": "albedo:albedo,dist:depth,shape:shape_index",
                       # direct light only: one shadow ray per sample, no noisy indirect bounces
                       "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0,
                                      "hide_emitters": True}},
        "sensor": {
            "type": "perspective", "fov": float(hfov), "fov_axis": "x",
            "near_clip": NEAR_CLIP_M, "far_clip": 1000.0,
            "film": {"type": "hdrfilm", "width": int(width), "height": int(height), "pixel_format": "rgba",
                     "rfilter": {"type": "box"}},
            "sampler": {"type": "independent", "sample_count": int(spp)},
        },
    }
    for i, pos in enumerate(lights.positions):
        scene[f"light_{i}"] = {"type": "point", "position": [float(v) for v in pos],
                               "intensity": {"type": "rgb", "value": float(lights.intensity)}}
    lit_keys: set[str] = set()
    for i, obj in enumerate(spec.objects):
        tri = _triangles(obj)
        if len(tri) == 0:
            continue
        # one texture per object, one tile over the whole object: nothing repeats, nothing wraps
        lo, hi = tri.reshape(-1, 3).min(0), tri.reshape(-1, 3).max(0)
        size = int(np.clip(np.ceil(np.max(hi - lo) / texel), 64, max_texture_px))
        tile = size * texel
        visual = getattr(obj, "visual", "noise") or "noise"
        color = tuple(float(c) for c in getattr(obj, "color", (0.6, 0.6, 0.6)))
        tex = getattr(obj, "texture", None)  # an explicit image (e.g. a printed marker) wins
        if tex is not None:
            tile = float(np.max(hi - lo))
        else:
            tex = make_texture(visual, color, size, seed=stable_seed(obj.name, seed), texel_m=tile / size)
        bsdf = mi.load_dict({"type": "diffuse", "reflectance": {
            "type": "bitmap", "bitmap": mi.Bitmap(tex), "raw": True, "filter_type": "bilinear",
            "wrap_mode": "mirror"}})
        mesh = build_mesh(mi, f"obj{i}_{obj.name}", tri, lo, tile)
        mesh.set_bsdf(bsdf)
        scene[f"obj{i}"] = mesh
        if visual in SELF_LIT_VISUALS:
            lit_keys.add(f"obj{i}")
    loaded = mi.load_dict(scene)
    # shape_index counts from 1 over the scene's shapes (0: no hit)
    self_lit = [k + 1 for k, shape in enumerate(loaded.shapes()) if shape.id() in lit_keys]
    return loaded, replace(lights, self_lit_shapes=tuple(self_lit))


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
