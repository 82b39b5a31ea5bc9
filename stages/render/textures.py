"""Procedural texture bitmaps for the photo renderer.

Each visual name ("wood", "brick", ...) maps to a generator that returns an (S, S, 3) float32
image in [0, 1], tinted by the object's colour. Every texture carries multi-octave noise and
random blobs at several sizes, so SIFT finds many distinctive features at any viewing distance
(a plain colour would leave structure from motion with nothing to match). Feature sizes are set
in texels, so a texture's world scale (texels per metre) fixes how large its features look. Glass is
the exception: a pane shows the daylight behind it, pale and bright (`_pane`), and the renderer shows it
unshaded (mitsuba_scene.SELF_LIT_VISUALS).
"""
from __future__ import annotations

import zlib

import cv2
import numpy as np

VISUALS = ("wood", "brick", "plaster", "tiles", "metal", "carpet", "glass", "checker", "noise", "plastic")


def stable_seed(*parts) -> int:
    """A seed from strings/ints that does not change between Python runs (unlike hash())."""
    return zlib.crc32("|".join(str(p) for p in parts).encode()) & 0x7FFFFFFF


def fractal_noise(rng: np.random.Generator, size: int, cells_px=(256, 128, 64, 32, 16, 8, 4),
                  persistence: float = 0.7, stretch: tuple[float, float] = (1.0, 1.0)) -> np.ndarray:
    """Sum of bicubically upsampled random grids with the given cell sizes (texels, largest first);
    (size, size) float32, zero mean, unit std. Features have the same size in texels whatever `size` is."""
    out = np.zeros((size, size), np.float32)
    amp = 1.0
    for cell in cells_px:
        cx = max(2, int(round(size / cell * stretch[0])))
        cy = max(2, int(round(size / cell * stretch[1])))
        grid = rng.standard_normal((cy, cx)).astype(np.float32)
        out += amp * cv2.resize(grid, (size, size), interpolation=cv2.INTER_CUBIC)
        amp *= persistence
    out -= out.mean()
    return out / (out.std() + 1e-8)


def blobs(rng: np.random.Generator, size: int, per_megatexel: float, radius_px: tuple[float, float]) -> np.ndarray:
    """Random soft dots of random sign, `per_megatexel` of them per 1024 x 1024 texels:
    (size, size) float32 in about [-1, 1]."""
    count = max(1, int(per_megatexel * (size / 1024.0) ** 2))
    canvas = np.zeros((size, size), np.float32)
    xs = rng.integers(0, size, count)
    ys = rng.integers(0, size, count)
    rs = rng.uniform(*radius_px, count)
    vs = rng.uniform(-1.0, 1.0, count)
    for x, y, r, v in zip(xs, ys, rs, vs):
        cv2.circle(canvas, (int(x), int(y)), max(1, int(r)), float(v), -1, lineType=cv2.LINE_AA)
    return cv2.GaussianBlur(canvas, (0, 0), 1.0)


def _detail(rng, size) -> np.ndarray:
    """The shared high-frequency layer: fine noise plus blobs of several sizes (in texels)."""
    return (0.6 * fractal_noise(rng, size, cells_px=(48, 24, 12, 6, 3), persistence=0.9)
            + 1.0 * blobs(rng, size, 900, (3.0, 10.0))
            + 0.7 * blobs(rng, size, 120, (10.0, 30.0)))


def _grid_cells(size: int, cell_w: float, cell_h: float, stagger: bool, mortar_px: int, rng):
    """Per-pixel cell brightness offsets and a mortar mask for bricks and tiles (cells in texels)."""
    ys, xs = np.mgrid[0:size, 0:size]
    row = (ys // cell_h).astype(int)
    shift = np.where(stagger & (row % 2 == 1), cell_w / 2, 0.0)
    col = ((xs + shift) // cell_w).astype(int)
    ny, nx = int(size // cell_h) + 2, int(size // cell_w) + 3
    cell_vals = rng.uniform(-1, 1, (ny, nx)).astype(np.float32)
    cell = cell_vals[row % ny, col % nx]
    mortar = ((xs + shift) % cell_w < mortar_px) | (ys % cell_h < mortar_px)
    return cell, mortar


def _pattern(visual: str, rng: np.random.Generator, size: int, texel_m: float) -> np.ndarray:
    """Luminance modulation (size, size) around 0 for a visual; the colour is applied later.

    texel_m sets the real-world size of regular structure (bricks 25 x 7 cm, tiles 30 cm, ...).
    """
    base = fractal_noise(rng, size)
    if visual == "wood":
        ys = np.mgrid[0:size, 0:size][0].astype(np.float32)
        warp = 18.0 * fractal_noise(rng, size, cells_px=(512, 256, 128), persistence=0.6)
        grain = np.sin(2 * np.pi * (ys + warp) / max(0.012 / texel_m, 6.0))
        streaks = fractal_noise(rng, size, cells_px=(16, 8, 4), stretch=(0.08, 1.0))
        return 0.45 * grain + 0.35 * streaks + 0.25 * base
    if visual in ("brick", "tiles"):
        if visual == "brick":
            cw, ch, stagger = 0.25 / texel_m, 0.075 / texel_m, True
        else:
            cw = ch = 0.3 / texel_m
            stagger = False
        cw, ch = max(cw, 24.0), max(ch, 8.0)
        cell, mortar = _grid_cells(size, cw, ch, stagger, max(2, int(0.01 / texel_m)), rng)
        out = 0.5 * cell + 0.25 * base
        return np.where(mortar, -1.4 + 0.2 * base, out).astype(np.float32)
    if visual == "metal":
        brushed = fractal_noise(rng, size, cells_px=(32, 16, 8, 4, 2), stretch=(0.02, 1.0))
        return 0.45 * brushed + 0.2 * base
    if visual == "carpet":
        return 0.35 * base + 0.6 * fractal_noise(rng, size, cells_px=(8, 4, 2), persistence=0.9)
    if visual == "checker":
        ys, xs = np.mgrid[0:size, 0:size]
        cell = max(int(0.1 / texel_m), 8)
        check = (((xs // cell) + (ys // cell)) % 2) * 2.0 - 1.0
        return 0.6 * check.astype(np.float32) + 0.25 * base
    if visual == "plastic":
        return 0.3 * base
    return 0.5 * base  # "plaster", "noise" and anything unknown


def make_texture(visual: str, color, size: int = 1024, seed: int = 0, texel_m: float = 0.002) -> np.ndarray:
    """An (size, size, 3) float32 texture in [0, 1] for `visual`, tinted by `color` (RGB in [0, 1]).

    texel_m: the world size of one texel (for regular patterns such as bricks). The same
    arguments always give the same image.
    """
    rng = np.random.default_rng(stable_seed(visual, tuple(np.round(color, 4)), size, seed))
    if visual == "glass":
        return _pane(rng, size, color)
    lum = _pattern(visual, rng, size, texel_m) + 0.6 * _detail(rng, size)
    # Hue jitter keeps neighbouring features distinguishable in colour as well as brightness.
    hue = 0.22 * np.stack([fractal_noise(rng, size, cells_px=(256, 64, 16)) for _ in range(3)], axis=-1)
    color = np.clip(np.asarray(color, np.float32), 0.01, 1.0)
    color = 0.7 * color + 0.15  # desaturate a little: saturated colours leave SIFT's grey image flat
    color = color * min(1.0, 0.6 / float(color.max()))  # headroom, so bright colours keep their detail
    factor = np.clip(1.0 + 0.45 * lum, 0.15, 2.2)[..., None]
    return np.clip(color[None, None, :] * factor * (1.0 + hue), 0.0, 1.0).astype(np.float32)


PANE_BRIGHTNESS = 0.85   # a pane's mean linear radiance (shown unshaded): daylight through it outshines the lit walls


def _pane(rng: np.random.Generator, size: int, color) -> np.ndarray:
    """A glass pane as a photo sees it: the daylight behind it and the reflections on it make it pale and bright,
    with a faint tint and less contrast (a window in a room photo is its brightest part). Fine detail at two thirds of
    the other textures' strength keeps features on it (the view through, smears on the glass) for structure from
    motion, without hiding its brightness."""
    lum = 0.5 * fractal_noise(rng, size, cells_px=(512, 256, 128)) + 0.6 * _detail(rng, size)
    tint = np.clip(np.asarray(color, np.float32), 0.01, 1.0)
    pale = PANE_BRIGHTNESS * (0.8 + 0.2 * tint / float(tint.max()))
    factor = np.clip(1.0 + 0.3 * lum, 0.5, 1.3)[..., None]
    return np.clip(pale[None, None, :] * factor, 0.0, 1.0).astype(np.float32)
