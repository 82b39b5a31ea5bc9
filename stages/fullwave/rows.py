"""rfir's RCS protocols on full-wave data: the BEM curves of the full-wave check as measurements
(command line: scripts/fullwave_rows.py).

For each case of the check (a 0.3 m PEC plate and a dihedral of two such plates; 2.4 GHz, V, 360
monostatic aspects in the x-y plane) writes <out>/<kind>.csv (a turntable measurement for `rfir import
csv`: isotropic antennas, `power = rcs`, the radar at range_m, even aspects `train` and odd `test`)
and <out>/<kind>.ply (the same screen as a triangle mesh for `rfir mesh-gaussians`, no labels: the
material is fitted). The BEM is far-field; the range only has to be far enough for the object
(2 D^2 / lambda = 1.4 m here). The commands that score rfir on them are in docs/results.md.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .meshes import dihedral_screen, plate_screen

COARSE_QUADS = 4   # quads per side of the written mesh: mesh-gaussians tiles it at its own spacing


def write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """ASCII PLY of vertices [V, 3] m and triangles [F, 3]."""
    lines = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}", "property float x", "property float y",
             "property float z", f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    lines += [f"{x:.6f} {y:.6f} {z:.6f}" for x, y, z in vertices]
    lines += [f"3 {a} {b} {c}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")


def write_csv(path: Path, case: dict, range_m: float) -> None:
    """The case's BEM curve as turntable rows (aspect = -azimuth about z, the import's convention)."""
    phi = np.radians(np.asarray(case["phi_deg"], float))
    rows = ["# antenna = isotropic", f"# polarisation = {case['polarization']}", "# power = rcs",
            "tx_x,tx_y,tx_z,rx_x,rx_y,rx_z,freq_hz,power_db,aspect_deg,range_m,split"]
    for i, (p, rcs) in enumerate(zip(phi, case["bem_dbsm"])):
        x, y = range_m * np.cos(p), range_m * np.sin(p)
        rows.append(f"{x:.6f},{y:.6f},0.001,{x:.6f},{y:.6f},-0.001,{case['freq_hz']:.6e},{rcs:.4f},"
                    f"{(-np.degrees(p)) % 360:.3f},{range_m:g},{'train' if i % 2 == 0 else 'test'}")
    path.write_text("\n".join(rows) + "\n")


def write_rows(check: Path, out: Path, range_m: float = 10.0) -> list[tuple[Path, Path, int]]:
    """Write <out>/<kind>.csv and <out>/<kind>.ply for every case of the check's JSON `check`.

    range_m: radar range, m. Returns (csv path, ply path, aspects) per case."""
    cases = json.loads(Path(check).read_text())["cases"]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for case in cases:
        kind = case["kind"]
        size = float(case["size_m"])
        v, f = plate_screen(size, COARSE_QUADS) if kind == "plate" else dihedral_screen(size, size, COARSE_QUADS)
        write_ply(out / f"{kind}.ply", v, f)
        write_csv(out / f"{kind}.csv", case, range_m)
        written.append((out / f"{kind}.csv", out / f"{kind}.ply", len(case["phi_deg"])))
    return written
