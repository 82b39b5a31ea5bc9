"""A tiny synthetic capture for the geom tests: a textured square plane photographed from a few views.

Photos are rendered analytically (ray-plane intersection, a checkerboard texture over a constant
backdrop), independent of the tracer; the `calib` artifact holds the true poses and sparse points
on the plane with a little noise; a PLY of the plane is the ground-truth mesh.
"""
from __future__ import annotations

import numpy as np
import pytest

BACKGROUND = np.array([0.55, 0.6, 0.66])
HALF = 0.2  # the plane spans [-HALF, HALF]^2 at z = 0, m


def look_at(eye, target=(0.0, 0.0, 0.0)):
    eye, target = np.asarray(eye, float), np.asarray(target, float)
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, y, z, eye
    return pose


def texture(p):
    """Checkerboard (5 cm squares) of two colours with a smooth ramp, at plane points [..., 3]."""
    cell = (np.floor(p[..., 0] / 0.05) + np.floor(p[..., 1] / 0.05)) % 2
    a, b = np.array([0.9, 0.3, 0.2]), np.array([0.15, 0.35, 0.8])
    base = np.where(cell[..., None] > 0, a, b)
    return np.clip(base * (0.75 + 0.25 * (p[..., 0:1] / HALF)), 0, 1)


def render_plane(pose, K, width, height):
    v, u = np.meshgrid(np.arange(height), np.arange(width), indexing="ij")
    d = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T @ pose[:3, :3].T
    o = pose[:3, 3]
    t = -o[2] / d[..., 2]
    p = o + t[..., None] * d
    inside = (t > 0) & (np.abs(p[..., 0]) < HALF) & (np.abs(p[..., 1]) < HALF)
    return np.where(inside[..., None], texture(p), BACKGROUND)


def make_capture(folder, n_views=6, width=64, height=48, n_points=400, seed=0):
    """Write images/, calib.h5 and plane.ply into folder; returns (calib path, mesh path)."""
    import cv2
    from plyfile import PlyData, PlyElement

    from rfir_core.artifacts import write_artifact
    from rfir_core.provenance import Provenance

    rng = np.random.default_rng(seed)
    (folder / "images").mkdir(parents=True, exist_ok=True)
    fx = 0.5 * width / np.tan(np.radians(30))
    K = np.array([[fx, 0, (width - 1) / 2], [0, fx, (height - 1) / 2], [0, 0, 1.0]])
    paths, poses = [], []
    for i in range(n_views):
        az, el = 2 * np.pi * i / n_views, np.radians(55 + 10 * (i % 2))
        eye = 0.7 * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        pose = look_at(eye)
        img = render_plane(pose, K, width, height)
        name = f"images/view_{i:03d}.png"
        cv2.imwrite(str(folder / name), cv2.cvtColor((img * 255).round().astype(np.uint8), cv2.COLOR_RGB2BGR))
        paths.append(name)
        poses.append(pose)
    pts = np.concatenate([rng.uniform(-HALF, HALF, (n_points, 2)), rng.normal(0, 0.002, (n_points, 1))], 1)
    rgb = (texture(pts) * 255).round().astype(np.uint8)
    n = n_views
    data = {
        "image_paths": np.asarray(paths, dtype=object), "image_sha256": np.asarray(["0" * 64] * n, dtype=object),
        "image_size": np.tile([width, height], (n, 1)), "intrinsics": np.tile(K, (n, 1, 1)),
        "world_from_camera": np.stack(poses), "reproj_error_px": np.zeros(n), "points_xyz": pts, "points_rgb": rgb,
        "points_track_length": np.full(n_points, 3), "alignment_sim3": np.eye(4),
    }
    calib = write_artifact(folder / "calib.h5", "calib", data, attrs={"metric": True}, provenance=Provenance(stage="test"))
    vert = np.array([(-HALF, -HALF, 0), (HALF, -HALF, 0), (HALF, HALF, 0), (-HALF, HALF, 0)],
                    dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    face = np.array([([0, 1, 2],), ([0, 2, 3],)], dtype=[("vertex_indices", "i4", (3,))])
    mesh = folder / "plane.ply"
    PlyData([PlyElement.describe(vert, "vertex"), PlyElement.describe(face, "face")]).write(str(mesh))
    return calib, mesh


@pytest.fixture(scope="session")
def plane_capture(tmp_path_factory):
    folder = tmp_path_factory.mktemp("plane")
    return make_capture(folder)


# Small, fast settings for the tests (every table of configs/geom.toml that matters).
def tiny_config(**over):
    from rfir_core.config import load_defaults

    cfg = load_defaults()["geom"]
    cfg.update({"max_image_width": 64, "test_every": 3, "iterations": 80, "max_init_points": 400,
                "checkpoint_every": 20, "rebuild_every": 20})
    cfg["densify"] = {**cfg["densify"], "every": 30, "from": 30, "until": 0.7, "max_gaussians": 1500}
    cfg["output"] = {**cfg["output"], "tsdf_voxel": 0.01}
    cfg["evaluate"] = {**cfg["evaluate"], "gt_mesh": "", "chamfer_points": 5000}
    for k, v in over.items():
        if isinstance(v, dict):
            cfg[k] = {**cfg[k], **v}
        else:
            cfg[k] = v
    return cfg


@pytest.fixture
def small_config():
    """tiny_config as a fixture (test modules cannot import conftest under --import-mode=importlib)."""
    return tiny_config
