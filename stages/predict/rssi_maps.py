"""The radio-map files of `rfir predict rssi`: values at the receivers as CSV, NPZ or TIFF, and the
best-server and coverage maps of several transmitters.

Values are path gain [dB], or received power [dBm] when a transmit power is given (value = path gain +
P_T). A receiver left out of a transmitter's map (too close to it) holds NaN there.

- CSV: one row per receiver: x_m, y_m, z_m, then the value (one column per transmitter when there are
  several, then best_tx, 1-based, 0 where no transmitter has a value, and best).
- NPZ: points_m [N, 3], tx_m [T, 3], values [T, N], best_tx [N] (0-based, -1: none), unit, quantity;
  on a grid also grid_values [T, ny, nx] (row 0 = smallest y), grid_origin_m [2] (centre of the first
  cell), grid_step_m, height_m.
- TIFF (grids only): one single-band float32 image per map, north up (row 0 = largest y), uncompressed,
  with the GeoTIFF tags ModelPixelScale (step, step, 0 m), ModelTiepoint (the top-left corner of the
  top-left cell, m) and a GeoKeyDirectory saying: user-defined frame, pixel is area, metres; no-data NaN.
"""
from __future__ import annotations

import csv
import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rfir_core.errors import ConfigError

FORMATS = ("csv", "npz", "tif")


@dataclass
class GridInfo:
    """A floor grid of receivers (rssi_checks.floor_grid): nx x ny cells of step_m [m] at height_m [m],
    cell centres from origin_m [2] (x, y of the first cell), points x-major (index = ix * ny + iy)."""

    nx: int
    ny: int
    origin_m: tuple
    step_m: float
    height_m: float

    def image(self, values: np.ndarray) -> np.ndarray:
        """values [nx * ny] as an image [ny, nx] with row 0 at the smallest y."""
        return np.asarray(values, np.float64).reshape(self.nx, self.ny).T


def parse_formats(items) -> list[str]:
    """--format values (repeated and/or comma-separated) -> distinct formats in FORMATS; ConfigError otherwise."""
    out = []
    for item in items or ():
        for word in str(item).split(","):
            word = word.strip().lower()
            if word in ("tiff", "geotiff"):
                word = "tif"
            if not word:
                continue
            if word not in FORMATS:
                raise ConfigError(f"--format {word!r}: expected one of {', '.join(FORMATS)} (comma-separated or repeated)")
            if word not in out:
                out.append(word)
    return out


def map_paths(out_path: Path, formats: list[str], num_tx: int) -> dict[str, list[Path]]:
    """The files each format writes beside the predictions artifact OUT.h5: OUT.csv, OUT.npz, OUT.tif (one
    transmitter) or OUT_tx1.tif .. OUT_txT.tif and OUT_best_tx.tif (several)."""
    out_path = Path(out_path)
    paths = {}
    for fmt in formats:
        if fmt == "tif" and num_tx > 1:
            names = [f"{out_path.stem}_tx{i + 1}.tif" for i in range(num_tx)] + [f"{out_path.stem}_best_tx.tif"]
            paths[fmt] = [out_path.with_name(n) for n in names]
        else:
            paths[fmt] = [out_path.with_suffix("." + fmt)]
    return paths


def best_server(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(index [N] of the strongest transmitter, -1 where none has a value; its value [N], NaN there) of
    values [T, N]."""
    values = np.asarray(values, np.float64)
    have = np.isfinite(values)
    filled = np.where(have, values, -np.inf)
    idx = np.argmax(filled, axis=0)
    best = np.take_along_axis(filled, idx[None], 0)[0]
    none = ~have.any(0)
    return np.where(none, -1, idx), np.where(none, np.nan, best)


def coverage_share(best: np.ndarray, threshold: float) -> tuple[float, int, int]:
    """(share in [0, 1], points covered, points with a value) of the points whose best value is >= threshold."""
    best = np.asarray(best, np.float64)
    have = np.isfinite(best)
    covered = int(np.count_nonzero(best[have] >= threshold))
    n = int(np.count_nonzero(have))
    return (covered / n if n else 0.0), covered, n


def _write_whole(path: Path, write) -> Path:
    """Call write(tmp) on a hidden file beside `path`, then move it onto `path`: a map file is there whole or not
    at all (an interrupted run leaves no half-written one). The hidden name keeps the suffix (np.savez adds .npz)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.partial{path.suffix}")
    try:
        write(tmp)
        tmp.replace(path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def write_csv(path: Path, points: np.ndarray, values: np.ndarray, column: str, best=None) -> Path:
    """CSV x_m,y_m,z_m,<column> (values [T, N]: T > 1 gives <column>_tx1.. and best_tx, best)."""
    t = len(values)
    header = ["x_m", "y_m", "z_m"] + ([column] if t == 1 else [f"{column}_tx{i + 1}" for i in range(t)])
    cols = [points[:, 0], points[:, 1], points[:, 2], *values]
    if t > 1:
        header += ["best_tx", f"best_{column}"]

    def write(tmp: Path) -> None:
        with open(tmp, "w", newline="") as handle:
            w = csv.writer(handle)
            w.writerow(header)
            for lo in range(0, len(points), 65536):
                block = np.stack([c[lo:lo + 65536] for c in cols], 1)
                rows = [[f"{v:.6g}" if np.isfinite(v) else "nan" for v in row] for row in block]
                if t > 1:
                    for row, i, b in zip(rows, best[0][lo:lo + 65536], best[1][lo:lo + 65536]):
                        row += [str(int(i) + 1), f"{b:.6g}" if np.isfinite(b) else "nan"]
                w.writerows(rows)
    return _write_whole(path, write)


def write_npz(path: Path, points: np.ndarray, values: np.ndarray, txs: np.ndarray, unit: str, quantity: str,
              best_idx: np.ndarray, grid: GridInfo | None) -> Path:
    """NPZ with the arrays named in the module docstring."""
    arrays = {"points_m": points, "tx_m": txs, "values": values, "best_tx": best_idx, "unit": np.asarray(unit),
              "quantity": np.asarray(quantity)}
    if grid is not None:
        arrays.update(grid_values=np.stack([grid.image(v) for v in values]), grid_origin_m=np.asarray(grid.origin_m),
                      grid_step_m=np.asarray(grid.step_m), height_m=np.asarray(grid.height_m))
    return _write_whole(path, lambda tmp: np.savez(tmp, **arrays))


# TIFF tag ids: baseline, then GeoTIFF (ModelPixelScale, ModelTiepoint, GeoKeyDirectory) and GDAL's no-data
_SHORT, _LONG, _DOUBLE, _ASCII = 3, 4, 12, 2


def write_tiff(path: Path, image: np.ndarray, grid: GridInfo) -> Path:
    """A single-band float32 little-endian TIFF of image [ny, nx] (row 0 = smallest y; written north up) with
    the grid's step and top-left corner in metres as GeoTIFF tags."""
    img = np.ascontiguousarray(np.asarray(image, np.float64)[::-1], dtype="<f4")
    ny, nx = img.shape
    pixels = img.tobytes()
    x0 = grid.origin_m[0] - grid.step_m / 2
    y_top = grid.origin_m[1] + (grid.ny - 0.5) * grid.step_m
    geokeys = [1, 1, 0, 3, 1024, 0, 1, 32767, 1025, 0, 1, 1, 3076, 0, 1, 9001]
    tags = [  # (tag, type, values)
        (256, _LONG, [nx]), (257, _LONG, [ny]), (258, _SHORT, [32]), (259, _SHORT, [1]), (262, _SHORT, [1]),
        (273, _LONG, [0]), (277, _SHORT, [1]), (278, _LONG, [ny]), (279, _LONG, [len(pixels)]),
        (284, _SHORT, [1]), (339, _SHORT, [3]),
        (33550, _DOUBLE, [grid.step_m, grid.step_m, 0.0]),
        (33922, _DOUBLE, [0.0, 0.0, 0.0, x0, y_top, 0.0]),
        (34735, _SHORT, geokeys),
        (42113, _ASCII, b"nan\x00"),
    ]
    fmt = {_SHORT: "<H", _LONG: "<I", _DOUBLE: "<d"}
    header = 8
    ifd_size = 2 + 12 * len(tags) + 4
    extra_at = header + ifd_size
    extra = b""
    entries = []
    offsets = {}
    for tag, typ, vals in tags:
        raw = vals if typ == _ASCII else b"".join(struct.pack(fmt[typ], v) for v in vals)
        count = len(vals)
        if len(raw) <= 4:
            entries.append((tag, typ, count, raw.ljust(4, b"\x00")))
        else:
            if len(extra) % 2:
                extra += b"\x00"
            offsets[tag] = extra_at + len(extra)
            entries.append((tag, typ, count, struct.pack("<I", offsets[tag])))
            extra += raw
    if len(extra) % 2:
        extra += b"\x00"
    pixel_at = extra_at + len(extra)
    ifd = struct.pack("<H", len(entries))
    for tag, typ, count, value in entries:
        if tag == 273:
            value = struct.pack("<I", pixel_at)
        ifd += struct.pack("<HHI", tag, typ, count) + value
    ifd += struct.pack("<I", 0)
    data = b"II" + struct.pack("<HI", 42, header) + ifd + extra + pixels
    return _write_whole(path, lambda tmp: tmp.write_bytes(data))


def write_maps(paths: dict[str, list[Path]], points: np.ndarray, values: np.ndarray, txs: np.ndarray, unit: str,
               quantity: str, grid: GridInfo | None) -> list[Path]:
    """Write every format of `paths` (map_paths); values [T, N] in `unit` ('dB' or 'dBm'); returns the files."""
    best = best_server(values)
    column = "rssi_dbm" if unit == "dBm" else "path_gain_db"
    written = []
    for fmt, files in paths.items():
        if fmt == "csv":
            written.append(write_csv(files[0], points, values, column, best if len(values) > 1 else None))
        elif fmt == "npz":
            written.append(write_npz(files[0], points, values, txs, unit, quantity, best[0], grid))
        elif fmt == "tif":
            if grid is None:
                raise ConfigError("--format tif needs receivers on a grid (--grid, or neither --rx nor measured points)")
            images = [grid.image(v) for v in values]
            if len(values) > 1:
                images.append(grid.image(np.where(best[0] >= 0, best[0] + 1.0, np.nan)))
            written += [write_tiff(f, im, grid) for f, im in zip(files, images)]
    return written
