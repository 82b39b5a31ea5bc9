"""Camera poses for the ground-truth photos (OpenCV axes: x right, y down, z forward; world z up).

Objects get rings of views on a spherical cap around the object, looking at its centre. Rooms get
three loops inside the room at different heights (looking across the room, at the walls, and
down at the furniture), each pose kept out of objects and away from surfaces right in front of it.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

# A ray caster: (origins (R,3), unit directions (R,3)) -> distance to the first hit (R,), inf on a miss.
RayDistance = Callable[[np.ndarray, np.ndarray], np.ndarray]


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """world_from_camera (4, 4) for a camera at `eye` looking at `target` (OpenCV axes, image up ~ `up`)."""
    eye, target, up = (np.asarray(v, np.float64) for v in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:  # looking straight along `up`: any right vector will do
        x = np.cross(z, [1.0, 0.0, 0.0] if abs(z[0]) < 0.9 else [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, y, z, eye
    return pose


def direction(yaw_rad: float, pitch_rad: float) -> np.ndarray:
    """Unit vector with azimuth `yaw` (from +x towards +y) and elevation `pitch` (positive up)."""
    return np.array([np.cos(pitch_rad) * np.cos(yaw_rad), np.cos(pitch_rad) * np.sin(yaw_rad), np.sin(pitch_rad)])


def intrinsics(width: int, height: int, hfov_deg: float) -> np.ndarray:
    """Pinhole K with square pixels and the principal point at the image centre.

    Pixel convention: OpenCV's (the centre of the top-left pixel is (0, 0)), so the centre of the
    image is ((w - 1) / 2, (h - 1) / 2).
    """
    fx = 0.5 * width / np.tan(np.radians(hfov_deg) / 2)
    return np.array([[fx, 0.0, (width - 1) / 2], [0.0, fx, (height - 1) / 2], [0.0, 0.0, 1.0]])


def object_poses(center, radius_m: float, n_views: int, K: np.ndarray, width: int, height: int,
                 rng: np.random.Generator, elevations_deg=None, fill: float = 1.0,
                 azimuth_span_deg: float = 360.0) -> np.ndarray:
    """(n, 4, 4) views on rings around a bounding sphere (centre, radius) that fills `fill` of the
    shorter image side; ring sizes follow cos(elevation), azimuths are staggered between rings.
    azimuth_span_deg < 360 puts the views on an arc (a partial orbit, for small test sets)."""
    center = np.asarray(center, np.float64)
    half = np.arctan(0.5 * min(width, height) / K[0, 0])
    dist = radius_m / np.sin(fill * half)
    if elevations_deg is None:
        n_rings = 3 if n_views <= 30 else 4
        elevations_deg = np.linspace(12.0, 62.0, n_rings)
    elev = np.radians(np.asarray(elevations_deg, np.float64))
    weights = np.cos(elev) / np.cos(elev).sum()
    counts = np.floor(weights * n_views).astype(int)
    counts[: n_views - counts.sum()] += 1
    poses = []
    for ring, (el, count) in enumerate(zip(elev, counts)):
        span = np.radians(min(azimuth_span_deg, 360.0))
        full = azimuth_span_deg >= 360.0
        offset = rng.uniform(0, 2 * np.pi) if full else (ring % 2) * 0.5 * span / max(count, 1)
        for k in range(count):
            az = offset + (span * k / count if full else span * k / max(count, 1))
            eye = center + dist * direction(az, el)
            target = center + rng.normal(0.0, 0.04 * radius_m, 3)
            poses.append(look_at(eye, target))
    return np.stack(poses)


def _blocked(point, boxes: np.ndarray, clearance_m: float) -> bool:
    """True if `point` lies within `clearance_m` of any box (B, 2, 3)."""
    if len(boxes) == 0:
        return False
    inside = np.all((point >= boxes[:, 0] - clearance_m) & (point <= boxes[:, 1] + clearance_m), axis=1)
    return bool(inside.any())


def obstacle_boxes(object_bounds: list[np.ndarray], scene_bounds: np.ndarray) -> np.ndarray:
    """AABBs of objects a camera must stay out of: all but the room shell (objects whose footprint
    covers most of the room, e.g. a floor, a ceiling or a single walls mesh)."""
    room_area = np.prod(scene_bounds[1, :2] - scene_bounds[0, :2])
    keep = []
    for box in object_bounds:
        ext = box[1] - box[0]
        if ext[0] * ext[1] > 0.5 * room_area:
            continue
        if min(ext[0], ext[1]) < 0.25 and max(ext[0], ext[1]) > 0.6 * min(scene_bounds[1, :2] - scene_bounds[0, :2]):
            # a thin wall slab along the room's side: the inset keeps cameras off it anyway
            continue
        keep.append(box)
    return np.asarray(keep).reshape(-1, 2, 3)


def room_poses(bounds: np.ndarray, n_views: int, obstacles: np.ndarray, rng: np.random.Generator,
               ray_distance: RayDistance | None = None, clearance_m: float = 0.3,
               min_view_distance_m: float = 1.2) -> np.ndarray:
    """(n, 4, 4) views inside a room: three loops (heights ~1.2, 1.6, 2.0 m) on an ellipse inside the
    room, looking across it, at the walls, and down at the furniture."""
    lo, hi = np.asarray(bounds[0], float), np.asarray(bounds[1], float)
    center = 0.5 * (lo + hi)
    half = 0.5 * (hi - lo)
    floor, ceiling = lo[2], hi[2]
    heights = [np.clip(floor + h, floor + 0.4, ceiling - 0.4) for h in (1.2, 1.6, 2.0)]
    # (height, yaw mode, pitch): inward looks across the room, outward at the near walls
    loops = [(heights[0], "in", -8.0), (heights[1], "out", 0.0), (heights[2], "in", -25.0)]
    counts = [n_views // 3 + (1 if i < n_views % 3 else 0) for i in range(3)]
    poses = []
    for (height, mode, pitch), count in zip(loops, counts):
        phase = rng.uniform(0, 2 * np.pi)
        for k in range(count):
            t = phase + 2 * np.pi * k / max(count, 1)
            poses.append(_room_pose(t, height, mode, pitch, center, half, obstacles, rng, ray_distance,
                                    clearance_m, min_view_distance_m, lo, hi))
    return np.stack(poses)


def _room_pose(t, height, mode, pitch_deg, center, half, obstacles, rng, ray_distance, clearance_m,
               min_view_distance_m, lo, hi) -> np.ndarray:
    """One valid pose near loop angle `t`; tries jittered candidates, then any free spot."""
    inner = np.maximum(half[:2] - 1.0, 0.3)
    for attempt in range(200):
        shrink = 0.55 if attempt < 100 else rng.uniform(0.1, 0.9)
        jitter = rng.normal(0.0, 0.15 * (1 + attempt / 20), 2)
        xy = center[:2] + shrink * inner * np.array([np.cos(t), np.sin(t)]) + jitter
        eye = np.array([xy[0], xy[1], height + rng.normal(0.0, 0.05)])
        eye[:2] = np.clip(eye[:2], lo[:2] + 0.5, hi[:2] - 0.5)
        if _blocked(eye, obstacles, clearance_m):
            continue
        radial = np.arctan2(eye[1] - center[1], eye[0] - center[0])
        yaw = radial + (np.pi if mode == "in" else 0.0) + rng.uniform(-0.5, 0.5)
        pitch = np.radians(pitch_deg + rng.uniform(-6, 6))
        d = direction(yaw, pitch)
        if ray_distance is not None:
            # the centre ray and the four image-corner-ish rays must not hit something right in front
            dirs = [d, direction(yaw + 0.35, pitch), direction(yaw - 0.35, pitch),
                    direction(yaw, pitch + 0.25), direction(yaw, pitch - 0.25)]
            dist = ray_distance(np.repeat(eye[None], len(dirs), 0), np.asarray(dirs))
            if dist[0] < min_view_distance_m or np.min(dist) < 0.5 * min_view_distance_m:
                continue
        return look_at(eye, eye + d)
    raise RuntimeError("could not place a camera inside the room: it is too cluttered")
