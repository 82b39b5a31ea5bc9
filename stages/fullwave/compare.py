"""Full-wave check of the PO backend: BEM (EFIE) vs `rfir_stages.po` on a PEC plate and a dihedral
(command line: scripts/fullwave_compare.py).

Monostatic, far field, 2.4 GHz, V polarisation (E along the plate edge / the dihedral fold), aspects
in the x-y plane. Writes `<out>/fullwave_vs_po.json` (curves, gaps by region, timings) and
`<out>/fullwave_vs_po.png`.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from rfir_stages.po import po_rcs

from .meshes import dihedral_screen, plate_screen
from .mie import C0

FREQ_HZ = 2.4e9
SIZE_M = 0.3
FAR_M = 1.0e4  # PO far-field mode takes the direction of tx/rx only
DYNAMIC_RANGE_DB = 40.0  # gap statistics skip aspects where BEM is this far below its peak (PO nulls)


def aspect_directions(count: int) -> tuple[np.ndarray, np.ndarray]:
    """(phi_deg (M,), unit directions (M,3)) evenly over 360 degrees in the x-y plane."""
    phi = np.arange(count) * 360.0 / count
    r = np.radians(phi)
    return phi, np.stack([np.cos(r), np.sin(r), np.zeros_like(r)], 1)


def _ang_dist(phi, centre):
    return np.abs((np.asarray(phi) - centre + 180.0) % 360.0 - 180.0)


def regions(kind: str, phi: np.ndarray) -> dict[str, np.ndarray]:
    """Boolean masks of the aspect regions compared (degrees)."""
    if kind == "plate":  # normal along +-x
        spec = (_ang_dist(phi, 0) <= 10) | (_ang_dist(phi, 180) <= 10)
        graze = (_ang_dist(phi, 90) <= 10) | (_ang_dist(phi, 270) <= 10)
        return {"specular (within 10 deg of broadside)": spec, "near grazing (within 10 deg of the plane)": graze,
                "wide angle (the rest)": ~(spec | graze)}
    flash = _ang_dist(phi, 45) <= 35  # inside the opening, away from the single-plate flashes at 0 and 90
    plates = np.zeros_like(flash)
    for c in (0, 90, 180, 270):
        plates |= _ang_dist(phi, c) <= 5
    return {"dihedral flash (10-80 deg, double bounce)": flash, "single-plate flashes (+-5 deg of 0/90/180/270)": plates,
            "rest (outside, edges, grazing)": ~(flash | plates)}


def gap_stats(bem_db: np.ndarray, po_db: np.ndarray, mask: np.ndarray) -> dict:
    """PO - BEM in dB over mask, skipping BEM values more than DYNAMIC_RANGE_DB below the BEM peak."""
    keep = mask & (bem_db > bem_db.max() - DYNAMIC_RANGE_DB)
    d = po_db[keep] - bem_db[keep]
    if not len(d):
        return {"aspects": 0}
    return {"aspects": int(len(d)), "median_abs_db": float(np.median(np.abs(d))), "mean_db": float(d.mean()),
            "p90_abs_db": float(np.percentile(np.abs(d), 90)), "max_abs_db": float(np.abs(d).max())}


def run_case(kind: str, n: int, aspects: int, polarization: str = "V") -> dict:
    """BEM and PO curves for 'plate' or 'dihedral' with n x n quads per plate face."""
    from .bem import bem_monostatic_rcs

    v, f = plate_screen(SIZE_M, n) if kind == "plate" else dihedral_screen(SIZE_M, SIZE_M, n)
    phi, u = aspect_directions(aspects)
    timings: dict = {}
    bem = bem_monostatic_rcs(v, f, FREQ_HZ, u, polarization, timings=timings)
    t0 = time.perf_counter()
    po = po_rcs(v, f, "pec", FAR_M * u, FAR_M * u, [FREQ_HZ], polarization=polarization,
                second_order=(kind == "dihedral"))[:, 0]
    timings["po_s"] = time.perf_counter() - t0
    bem_db, po_db = 10 * np.log10(np.maximum(bem, 1e-30)), 10 * np.log10(np.maximum(po, 1e-30))
    lam = C0 / FREQ_HZ
    out = {"kind": kind, "size_m": SIZE_M, "freq_hz": FREQ_HZ, "polarization": polarization, "quads_per_side": n,
           "edge_m": SIZE_M / n, "triangles": int(len(f)), "phi_deg": phi.tolist(), "bem_dbsm": bem_db.tolist(),
           "po_dbsm": po_db.tolist(), "timings": timings,
           "regions": {name: gap_stats(bem_db, po_db, m) for name, m in regions(kind, phi).items()}}
    if kind == "plate":
        closed = 10 * np.log10(4 * np.pi * (SIZE_M * SIZE_M) ** 2 / lam**2)
        i0 = int(np.argmin(_ang_dist(phi, 0)))
        out["broadside"] = {"closed_form_dbsm": float(closed), "bem_dbsm": float(bem_db[i0]), "po_dbsm": float(po_db[i0])}
    else:
        closed = 10 * np.log10(8 * np.pi * (SIZE_M * SIZE_M) ** 2 / lam**2)
        i45 = int(np.argmin(_ang_dist(phi, 45)))
        out["bisector"] = {"closed_form_dbsm": float(closed), "bem_dbsm": float(bem_db[i45]), "po_dbsm": float(po_db[i45])}
    return out


def plot(cases: list[dict], path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(len(cases), 1, figsize=(9, 3.6 * len(cases)), squeeze=False)
    for ax, c in zip(axes[:, 0], cases):
        ax.plot(c["phi_deg"], c["bem_dbsm"], "k-", lw=1.4, label="BEM (EFIE, bempp-cl)")
        ax.plot(c["phi_deg"], c["po_dbsm"], "r--", lw=1.0, label="PO (--rcs-backend po)")
        top = max(max(c["bem_dbsm"]), max(c["po_dbsm"]))
        ax.set_ylim(top - 50, top + 5)
        ax.set_xlim(0, 360)
        ax.set_xticks(range(0, 361, 45))
        ax.set_ylabel("RCS [dBsm]")
        ax.set_title(f"PEC {c['kind']} {c['size_m']} m, {c['freq_hz'] / 1e9:g} GHz, {c['polarization']} pol, "
                     f"{c['timings']['dofs']} unknowns")
        ax.grid(alpha=0.3)
        ax.legend(loc="lower left", fontsize=8)
    axes[-1, 0].set_xlabel("aspect phi [deg] (plate: normal at 0/180; dihedral: bisector at 45)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_check(out: Path, aspects: int = 360, plate_n: int = 24, dihedral_n: int = 17,
                command: str = "") -> list[dict]:
    """Run both cases and write <out>/fullwave_vs_po.json (with `command`, the line that made it) and .png.

    aspects: aspect count over 360 degrees; plate_n / dihedral_n: quads per side of the plate / of each
    dihedral face (24: edges lambda/10 at 2.4 GHz). Returns the cases (run_case's dicts)."""
    cases = [run_case("plate", plate_n, aspects), run_case("dihedral", dihedral_n, aspects)]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tmp = out / "fullwave_vs_po.json.part"
    tmp.write_text(json.dumps({"command": command, "cases": cases}, indent=1))
    tmp.replace(out / "fullwave_vs_po.json")     # never a half-written check
    plot(cases, out / "fullwave_vs_po.png")
    return cases
