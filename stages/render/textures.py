"""Procedural texture bitmaps for the photo renderer.

Each visual name ("wood", "brick", ...) maps to a generator that returns an (S, S, 3) float32
image in [0, 1], tinted by the object's colour. Every texture carries multi-octave noise and
random blobs at several sizes, so SIFT finds many distinctive features at any viewing distance
(a plain colour would leave structure from motion with nothing to match). Textures are seamless
only where it does not matter: objects use world-scale UVs that rarely wrap.
"""
from __future__ import annotations

import zlib

import cv2
import numpy as np

VISUALS = ("wood", "brick", "plaster", "tiles", "metal", "carpet", "glass", "checker", "noise", "plastic")


def _stable_seed(*parts) -> int:
    """A seed from strings/ints that does not change between Python runs (unlike hash())."""
    return zlib.crc32("|".join(str(p) for p in parts).encode()) & 0x7FFFFFFF


def fractal_noise(rng: np.random.Generator, size: int, octaves=(4, 8, 16, 32, 64, 128, 256),
                  persistence: float = 0.7, stretch: tuple[float, float] = (1.0, 1.0)) -> np.ndarray:
    """Sum of bicubically upsampled random grids; (size, size) float32, zero mean, unit std."""
    out = np.zeros((size, size), np.float32)
    amp = 1.0
    for cells in octaves:
        cx = max(2, int(cells * stretch[0]))
        cy = max(2, int(cells * stretch[1]))
        grid = rng.standard_normal((cy, cx)).astype(np.float32)
        out += amp * cv2.resize(grid, (size, size), interpolation=cv2.INTER_CUBIC)
        amp *= persistence
    out -= out.mean()
    return out / (out.std() + 1e-8)


def blobs(rng: np.random.Generator, size: int, count: int, radius_px: tuple[float, float]) -> np.ndarray:
    """Random soft dots of random sign: (size, size) float32 in about [-1, 1]."""
    canvas = np.zeros((size, size), np.float32)
    xs = rng.integers(0, size, count)
    ys = rng.integers(0, size, count)
    rs = rng.uniform(*radius_px, count)
    vs = rng.uniform(-1.0, 1.0, count)
    for x, y, r, v in zip(xs, ys, rs, vs):
        cv2.circle(canvas, (int(x), int(y)), max(1, int(r)), float(v), -1, lineType=cv2.LINE_AA)
    return cv2.GaussianBlur(canvas, (0, 0), 1.0)


def _detail(rng, size) -> np.ndarray:
    """The shared high-frequency layer: fine noise plus blobs of several sizes."""
    scale = size / 1024.0
    return (0.5 * fractal_noise(rng, size, octaves=(16, 32, 64, 128, 256), persistence=0.9)
            + 1.0 * blobs(rng, size, int(900 * scale ** 2), (3.0 * scale, 10.0 * scale))
            + 0.8 * blobs(rng, size, int(120 * scale ** 2), (10.0 * scale, 36.0 * scale)))


def _grid_cells(size: int, nx: int, ny: int, stagger: bool, mortar_px: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel cell brightness offsets and a mortar mask for bricks and tiles."""
    ys, xs = np.mgrid[0:size, 0:size]
    cw, ch = size / nx, size / ny
    row = (ys // ch).astype(int)
    shift = np.where(stagger & (row % 2 == 1), cw / 2, 0.0)
    col = ((xs + shift) // cw).astype(int)
    cell_vals = rng.uniform(-1, 1, (ny + 1, nx + 2)).astype(np.float32)
    cell = cell_vals[row % (ny + 1), col % (nx + 2)]
    in_x = (xs + shift) % cw
    in_y = ys % ch
    mortar = (in_x < mortar_px) | (in_y < mortar_px)
    return cell, mortar


def _pattern(visual: str, rng: np.random.Generator, size: int) -> np.ndarray:
    """Luminance modulation (size, size) around 0 for a visual; the colour is applied later."""
    base = fractal_noise(rng, size)
    if visual == "wood":
        ys, xs = np.mgrid[0:size, 0:size].astype(np.float32)
        warp = 18.0 * fractal_noise(rng, size, octaves=(2, 4, 8), persistence=0.6)
        grain = np.sin(2 * np.pi * (ys + warp) / (size / 24.0))
        streaks = fractal_noise(rng, size, octaves=(64, 128, 256), stretch=(0.08, 1.0))
        return 0.45 * grain + 0.35 * streaks + 0.25 * base
    if visual in ("brick", "tiles"):
        nx, ny, stagger = (8, 16, True) if visual == "brick" else (10, 10, False)
        cell, mortar = _grid_cells(size, nx, ny, stagger, 6, rng)
        out = 0.5 * cell + 0.25 * base
        return np.where(mortar, -1.4 + 0.2 * base, out).astype(np.float32)
    if visual == "metal":
        brushed = fractal_noise(rng, size, octaves=(32, 64, 128, 256, 512), stretch=(0.02, 1.0))
        return 0.45 * brushed + 0.2 * base
    if visual == "carpet":
        return 0.35 * base + 0.6 * fractal_noise(rng, size, octaves=(128, 256, 512), persistence=0.9)
    if visual == "checker":
        ys, xs = np.mgrid[0:size, 0:size]
        check = (((xs // (size // 8)) + (ys // (size // 8))) % 2) * 2.0 - 1.0
        return 0.6 * check.astype(np.float32) + 0.25 * base
    if visual == "glass":
        return 0.25 * base
    if visual == "plastic":
        return 0.2 * base
    return 0.5 * base  # "plaster", "noise" and anything unknown


def make_texture(visual: str, color, size: int = 1024, seed: int = 0) -> np.ndarray:
    """An (size, size, 3) float32 texture in [0, 1] for `visual`, tinted by `color` (RGB in [0, 1]).

    The same (visual, color, size, seed) always gives the same image.
    """
    rng = np.random.default_rng(_stable_seed(visual, tuple(np.round(color, 4)), size, seed))
    lum = _pattern(visual, rng, size) + 0.6 * _detail(rng, size)
    # Hue jitter keeps neighbouring features distinguishable in colour as well as brightness.
    hue = 0.22 * np.stack([fractal_noise(rng, size, octaves=(4, 16, 64)) for _ in range(3)], axis=-1)
    color = np.clip(np.asarray(color, np.float32), 0.01, 1.0)
    factor = np.clip(1.0 + 0.45 * lum, 0.15, 2.2)[..., None]
    return np.clip(color[None, None, :] * factor * (1.0 + hue), 0.0, 1.0).astype(np.float32)
