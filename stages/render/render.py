"""render_views: poses, Mitsuba rendering, PNGs, depth maps and the `cameras` artifact."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rfir_core.progress import NullProgress, Progress

from .mitsuba_scene import NEAR_CLIP_M, build_scene, mitsuba_to_world, mitsuba_variant, ray_caster
from .poses import intrinsics, obstacle_boxes, object_poses, room_poses


@dataclass
class RenderResult:
    """What render_views wrote.

    image_paths: PNG files in view order; depth_paths: .npy depth maps (empty if not asked for);
    cameras_path: the `cameras` artifact; intrinsics (N,3,3) px; world_from_camera (N,4,4) m.
    """

    image_paths: list[Path]
    cameras_path: Path
    intrinsics: np.ndarray
    world_from_camera: np.ndarray
    image_size: tuple[int, int]
    depth_paths: list[Path] = field(default_factory=list)
    seconds: float = 0.0


def default_view_count(spec) -> int:
    """60 views around an object, 120 inside a room."""
    return 120 if spec.kind == "room" else 60


def scene_poses(spec, n_views: int, K: np.ndarray, width: int, height: int, seed: int,
                ray_distance=None) -> np.ndarray:
    """Camera poses (n, 4, 4) for a scene: rings around an object, loops inside a room."""
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(spec.bounds[0], float), np.asarray(spec.bounds[1], float)
    if spec.kind == "room":
        boxes = [np.stack([o.vertices.min(0), o.vertices.max(0)]) for o in spec.objects if len(o.vertices)]
        return room_poses(np.stack([lo, hi]), n_views, obstacle_boxes(boxes, np.stack([lo, hi])), rng, ray_distance)
    parts = [o.vertices for o in spec.objects if len(o.vertices)]
    if not parts:
        raise ValueError(f"scene {spec.name!r} has no geometry to photograph")
    verts = np.concatenate(parts)
    center = 0.5 * (verts.min(0) + verts.max(0))
    radius = float(np.max(np.linalg.norm(verts - center, axis=1)))
    return object_poses(center, radius, n_views, K, width, height, rng)


def _to_srgb8(linear: np.ndarray) -> np.ndarray:
    x = np.clip(linear, 0.0, 1.0)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.round(srgb * 255.0).astype(np.uint8)


def _depth_from_distance(dist: np.ndarray, alpha: np.ndarray, K: np.ndarray, near_clip_m: float) -> np.ndarray:
    """Mitsuba's depth AOV (coverage-weighted ray distance, counted from the near clip plane, where
    its camera rays start) -> depth along the camera z axis; 0 where nothing was hit."""
    h, w = dist.shape
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    x = (u - K[0, 2]) / K[0, 0]
    y = (v - K[1, 2]) / K[1, 1]
    hit = alpha > 1e-3
    t = np.where(hit, dist / np.maximum(alpha, 1e-3), 0.0)
    return np.where(hit, t / np.sqrt(1.0 + x * x + y * y) + near_clip_m, 0.0).astype(np.float32)


def render_views(spec, out_dir: str | Path, n_views: int | None = None, width: int = 640, height: int = 480,
                 seed: int = 0, progress: Progress | None = None, *, hfov_deg: float = 60.0, spp: int = 16,
                 write_depth: bool = True, poses: np.ndarray | None = None,
                 texture_px: int = 1024) -> RenderResult:
    """Render `n_views` photos of `spec` (SceneSpec) into `out_dir` and write `cameras.h5`.

    n_views defaults to 60 (objects) or 120 (rooms); `poses` (N,4,4, OpenCV world_from_camera)
    overrides the generated ones; texture_px scales the texture resolution (1024: 4 mm texels in
    rooms, 1/1024 of the object's size for objects). Deterministic for a given seed.
    """
    from rfir_core.artifacts import write_artifact
    from rfir_core.provenance import Provenance

    progress = progress or NullProgress()
    start = time.time()
    out_dir = Path(out_dir)
    (out_dir / "images").mkdir(parents=True, exist_ok=True)
    if write_depth:
        (out_dir / "depth").mkdir(parents=True, exist_ok=True)
    K = intrinsics(width, height, hfov_deg)
    with mitsuba_variant() as mi:
        scene, lights = build_scene(mi, spec, width, height, K, spp, seed=seed, texture_px=texture_px)
        if poses is None:
            poses = scene_poses(spec, n_views or default_view_count(spec), K, width, height, seed,
                                ray_caster(mi, scene))
        poses = np.asarray(poses, np.float64)
        params = mi.traverse(scene)
        images, depths = [], []
        bg = np.asarray(lights.background, np.float32)
        with progress.task(f"render {spec.name}", total=len(poses)) as task:
            for i, pose in enumerate(poses):
                params["sensor.to_world"] = mi.Transform4f(mitsuba_to_world(pose).tolist())
                params.update()
                raw = np.array(mi.render(scene, seed=seed * 100003 + i), dtype=np.float32)
                rgb, alpha, albedo, dist, shape = raw[..., :3], raw[..., 3], raw[..., 4:7], raw[..., 7], raw[..., 8]
                linear = rgb + lights.ambient * albedo + (1.0 - alpha)[..., None] * bg
                # a pane's pixel is its texture, whatever the room's lights; the AOV is the mean index over the
                # pixel's samples, so a pixel on a pane's edge keeps its shaded value (unless two other shapes'
                # indices happen to average to the pane's: a stray pixel on an edge)
                lit = np.isin(shape, lights.self_lit_shapes)
                linear[lit] = albedo[lit]
                path = out_dir / "images" / f"view_{i:03d}.png"
                _write_png(path, _to_srgb8(linear))
                images.append(path)
                if write_depth:
                    dpath = out_dir / "depth" / f"view_{i:03d}.npy"
                    np.save(dpath, _depth_from_distance(dist, alpha, K, NEAR_CLIP_M))
                    depths.append(dpath)
                task.advance(1)
    n = len(poses)
    Ks = np.repeat(K[None], n, axis=0)
    cameras_path = out_dir / "cameras.h5"
    prov = Provenance(stage="simulate", extra={"renderer": "mitsuba " + _mitsuba_name(), "spp": spp,
                                               "hfov_deg": hfov_deg, "seed": seed})
    write_artifact(cameras_path, "cameras", {
        "image_names": np.array([p.name for p in images]),
        "intrinsics": Ks,
        "world_from_camera": poses,
        "image_size": np.tile(np.array([width, height], np.int64), (n, 1)),
    }, attrs={"scene": spec.name}, provenance=prov)
    return RenderResult(images, cameras_path, Ks, poses, (width, height), depths, time.time() - start)


def _mitsuba_name() -> str:
    import mitsuba as mi

    return f"{mi.__version__} {mi.variant()}"


def _write_png(path: Path, rgb8: np.ndarray) -> None:
    import cv2

    if not cv2.imwrite(str(path), rgb8[..., ::-1]):
        raise OSError(f"could not write {path}")
