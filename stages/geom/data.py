"""Training views for stage `geom`: calibrated photos, resized, with their rays.

Conventions (docs/guide/photos-to-scene.md): pinhole K in pixels with OpenCV's pixel centres (top-left pixel
centre at (0, 0)); `world_from_camera` [4, 4] maps OpenCV camera axes (x right, y down, z
forward) to the world frame (z up, metres).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from rfir_core.errors import InputFileError, StageError


@dataclass
class View:
    """One calibrated photo at training resolution.

    image: [H, W, 3] float32 RGB in [0, 1]; K: [3, 3] px (for this resolution);
    world_from_camera: [4, 4]; name: file name; split: 0 train, 1 held out.
    """

    name: str
    image: np.ndarray
    K: np.ndarray
    world_from_camera: np.ndarray
    split: int

    @property
    def height(self) -> int:
        return int(self.image.shape[0])

    @property
    def width(self) -> int:
        return int(self.image.shape[1])

    @property
    def centre(self) -> np.ndarray:
        """Camera centre [3] in metres (world)."""
        return self.world_from_camera[:3, 3]


def scaled_intrinsics(K: np.ndarray, scale: float) -> np.ndarray:
    """K for an image resized by `scale` (pixel centres: u' = (u + 0.5) s - 0.5)."""
    out = np.array(K, dtype=np.float64)
    out[0, 0] *= scale
    out[1, 1] *= scale
    out[0, 1] *= scale
    out[0, 2] = (K[0, 2] + 0.5) * scale - 0.5
    out[1, 2] = (K[1, 2] + 0.5) * scale - 0.5
    return out


def read_image(path: Path, width: int, expect_size: tuple[int, int] | None = None) -> np.ndarray:
    """RGB float32 [H', W', 3] in [0, 1], area-resampled to `width` columns (no upscaling).

    expect_size: (width, height) the photo must have (px), else InputFileError."""
    import cv2

    raw = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if raw is None:
        raise InputFileError("cannot read image", path=path)
    rgb = cv2.cvtColor(raw, cv2.COLOR_BGR2RGB)
    h, w = rgb.shape[:2]
    if expect_size is not None and (w, h) != tuple(expect_size):
        raise InputFileError(f"image is {w} x {h} px, the calibration says {expect_size[0]} x {expect_size[1]}", path=path)
    if width < w:
        height = max(1, int(round(h * width / w)))
        rgb = cv2.resize(rgb, (width, height), interpolation=cv2.INTER_AREA)
    return rgb.astype(np.float32) / 255.0


def load_views(calib, calib_path: Path, max_width: int, test_every: int) -> list[View]:
    """Views of a `calib` artifact at most `max_width` pixels wide; every `test_every`-th view
    (starting with the `test_every // 2`-th) is held out (0: none)."""
    paths = [str(p) for p in calib["image_paths"]]
    sizes = np.asarray(calib["image_size"])
    views = []
    for i, rel in enumerate(paths):
        path = Path(rel)
        if not path.is_absolute():
            path = calib_path.parent / path
        if not path.is_file():
            raise InputFileError(f"image {rel!r} named by the calibration is missing", path=path)
        w0 = int(sizes[i, 0])
        width = min(int(max_width), w0) if max_width > 0 else w0
        image = read_image(path, width, (w0, int(sizes[i, 1])))
        scale = image.shape[1] / w0
        split = 1 if test_every > 0 and i % test_every == test_every // 2 else 0
        views.append(View(Path(rel).name, image, scaled_intrinsics(calib["intrinsics"][i], scale),
                          np.asarray(calib["world_from_camera"][i], dtype=np.float64), split))
    if not any(v.split == 0 for v in views):
        raise StageError(f"{calib_path}: no training views left (test_every={test_every})")
    return views


def camera_rays(view: View, device="cpu", dtype=torch.float32) -> tuple[torch.Tensor, torch.Tensor]:
    """Ray origin [3] (camera centre, m) and unit directions [H, W, 3] (world) through pixel centres."""
    v, u = np.meshgrid(np.arange(view.height, dtype=np.float64), np.arange(view.width, dtype=np.float64), indexing="ij")
    pix = np.stack([u, v, np.ones_like(u)], axis=-1)
    cam = pix @ np.linalg.inv(view.K).T
    world = cam @ view.world_from_camera[:3, :3].T
    world /= np.linalg.norm(world, axis=-1, keepdims=True)
    origin = torch.as_tensor(view.centre, dtype=dtype, device=device)
    return origin, torch.as_tensor(world, dtype=dtype, device=device)


def z_from_distance(view: View, distance: np.ndarray) -> np.ndarray:
    """Depth along the camera z axis [H, W] from distance along the unit pixel rays [H, W]."""
    v, u = np.meshgrid(np.arange(view.height), np.arange(view.width), indexing="ij")
    cam = np.stack([u, v, np.ones_like(u)], axis=-1) @ np.linalg.inv(view.K).T
    return distance / np.linalg.norm(cam, axis=-1)


def background_colour(views: list[View], border_px: int = 2) -> np.ndarray:
    """Median RGB [3] of the image borders of the training views (the backdrop behind the scene)."""
    pixels = []
    for v in views:
        if v.split != 0:
            continue
        im = v.image
        b = max(1, min(border_px, im.shape[0] // 4, im.shape[1] // 4))
        pixels += [im[:b].reshape(-1, 3), im[-b:].reshape(-1, 3), im[:, :b].reshape(-1, 3), im[:, -b:].reshape(-1, 3)]
    return np.median(np.concatenate(pixels), axis=0).astype(np.float32)
