"""Gaussians as a PLY in the attribute layout that 3D Gaussian splatting viewers read.

One `vertex` element, float32 properties, one row per Gaussian:
x y z | nx ny nz | f_dc_0..2 | f_rest_0..44 | opacity | scale_0..2 | rot_0..3
- positions in metres (world frame, z up);
- nx ny nz: the learned unit normal (viewers ignore it; rfir reads it back);
- f_dc: degree-0 spherical-harmonic coefficients, RGB = 0.5 + SH_C0 f_dc with SH_C0 = 1 / (2 sqrt(pi));
  f_rest (degrees 1-3, channel-major) are zero: the appearance is view-independent;
- opacity: the logit of the opacity; scale: log standard deviations (m); rot: quaternion w, x, y, z.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

SH_C0 = 0.28209479177387814
NUM_REST = 45


def _logit(p: np.ndarray) -> np.ndarray:
    p = np.clip(p, 1e-6, 1 - 1e-6)
    return np.log(p / (1 - p))


def write_gaussian_ply(path: str | Path, fields: dict[str, np.ndarray]) -> Path:
    """Write scene fields (`gaussians/means`, ... as in the scene artifact) as a splatting PLY (atomically)."""
    from plyfile import PlyData, PlyElement

    path = Path(path)
    means = np.asarray(fields["gaussians/means"], dtype=np.float32)
    n = len(means)
    colors = np.asarray(fields.get("gaussians/colors", np.full((n, 3), 0.5)), dtype=np.float64)[:, :3]
    cols = {
        "x": means[:, 0], "y": means[:, 1], "z": means[:, 2],
        **{f"n{a}": np.asarray(fields["gaussians/normals"])[:, i] for i, a in enumerate("xyz")},
        **{f"f_dc_{i}": (colors[:, i] - 0.5) / SH_C0 for i in range(3)},
        **{f"f_rest_{i}": np.zeros(n) for i in range(NUM_REST)},
        "opacity": _logit(np.asarray(fields["gaussians/opacities"], dtype=np.float64)),
        **{f"scale_{i}": np.asarray(fields["gaussians/log_scales"])[:, i] for i in range(3)},
        **{f"rot_{i}": np.asarray(fields["gaussians/rotations"])[:, i] for i in range(4)},
    }
    rows = np.empty(n, dtype=[(name, "f4") for name in cols])
    for name, values in cols.items():
        rows[name] = values
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.partial")
    try:
        PlyData([PlyElement.describe(rows, "vertex")], text=False).write(str(tmp))
        tmp.replace(path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def read_gaussian_ply(path: str | Path) -> dict[str, np.ndarray]:
    """Read a splatting PLY back into scene fields (float64; colours from the f_dc terms, clipped to [0, 1])."""
    from plyfile import PlyData

    v = PlyData.read(str(path))["vertex"]

    def stack(names):
        return np.stack([np.asarray(v[n], dtype=np.float64) for n in names], axis=1)

    out = {
        "gaussians/means": stack(["x", "y", "z"]),
        "gaussians/log_scales": stack([f"scale_{i}" for i in range(3)]),
        "gaussians/rotations": stack([f"rot_{i}" for i in range(4)]),
        "gaussians/opacities": 1.0 / (1.0 + np.exp(-np.asarray(v["opacity"], dtype=np.float64))),
        "gaussians/colors": np.clip(0.5 + SH_C0 * stack([f"f_dc_{i}" for i in range(3)]), 0.0, 1.0),
    }
    if "nx" in v.data.dtype.names:
        out["gaussians/normals"] = stack(["nx", "ny", "nz"])
    return out
