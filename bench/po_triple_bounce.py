"""Cost and effect of the PO solver's third bounce (max_bounces 3 against 2), back to back in one process.

    .venv/bin/python bench/po_triple_bounce.py                # lego and trihedral, 2 / 3 / 2 / 3 bounces
    .venv/bin/python bench/po_triple_bounce.py --reference    # + the lego with 1.3 mm tubes and 3 bounces

lego: its scene mesh with ITU slabs, near field, radar at 3 m on a horizontal circle every 2 degrees,
2.4 and 5.8 GHz (as the convergence table of docs/po.md); trihedral: a = 0.15 m, PEC, near field, 3 m,
61 aspects within 30 degrees of its axis. Prints wall and CPU time per run, the load average, the
3 / 2 time ratio, and how far the lego's curve moves (mean / max |dB| per frequency).
"""
from __future__ import annotations

import argparse
import os
import time

import numpy as np

from rfir_stages.po import po_scattered_field, scene_mesh, trihedral_mesh
from rfir_stages.simulate.scenes import build_scene

FREQS = np.array([2.4e9, 5.8e9])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--reference", action="store_true", help="also the lego with 1.3 mm tubes (about 5x the time)")
    a = ap.parse_args()
    v, f, mats, th = scene_mesh(build_scene("lego"))
    az = np.radians(np.arange(0.0, 360.0, 2.0))
    pos = 3.0 * np.stack([np.cos(az), np.sin(az), 0.0 * az], 1)
    tv, tf = trihedral_mesh(0.15, 1)
    phi = np.radians(np.arange(-30.0, 31.0, 1.0)) + np.pi / 4
    el = np.arcsin(1.0 / np.sqrt(3.0))
    tpos = 3.0 * np.stack([np.cos(el) * np.cos(phi), np.cos(el) * np.sin(phi), np.full_like(phi, np.sin(el))], 1)
    po_scattered_field(tv, tf, "pec", tpos[:1], tpos[:1], FREQS)   # imports and Open3D start-up, not timed

    def lego(b, **kw):
        return po_scattered_field(v, f, mats, pos, pos, FREQS, face_thickness=th, near_field=True, second_order=True,
                                  max_bounces=b, **kw)

    def trihedral(b):
        return po_scattered_field(tv, tf, "pec", tpos, tpos, FREQS, near_field=True, second_order=True, max_bounces=b)

    curves = {}
    for name, call in (("lego", lego), ("trihedral", trihedral)):
        wall = {2: [], 3: []}
        for b in (2, 3, 2, 3):
            t0, c0 = time.perf_counter(), time.process_time()
            curves[name, b] = call(b)
            wall[b].append(time.perf_counter() - t0)
            print(f"{name} max_bounces={b}: wall {wall[b][-1]:.2f} s, cpu {time.process_time() - c0:.2f} s, "
                  f"load average {os.getloadavg()[0]:.2f}", flush=True)
        print(f"{name}: 3 / 2 bounces wall-time ratio {sum(wall[3]) / sum(wall[2]):.2f}")
    db = {b: 20 * np.log10(np.abs(curves["lego", b])) for b in (2, 3)}
    move = np.abs(db[3] - db[2])
    print("lego, |3 - 2 bounces| dB per frequency: mean", np.round(move.mean(0), 3), "max", np.round(move.max(0), 2))
    if a.reference:
        ref = 20 * np.log10(np.abs(lego(3, sbr_spacing_m=0.0013)))
        for b in (2, 3):
            print(f"lego, {b} bounces vs 3 with 1.3 mm tubes: MAE dB per frequency", np.round(np.abs(db[b] - ref).mean(0), 3))


if __name__ == "__main__":
    main()
