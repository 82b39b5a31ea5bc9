"""Benchmark of the PO RCS solver (issue 12): a 20k-facet object, 360 aspects, 2 frequencies.

    .venv/bin/python bench/bench_po.py                 # sphere (20 480 facets), 360 x 2
    .venv/bin/python bench/bench_po.py --object car    # Sionna low-poly car, subdivided to >= 20k facets
    .venv/bin/python bench/bench_po.py --wideband 2000 --aspects 36
    .venv/bin/python bench/bench_po.py --object h-target --wideband 2000 --near-field --second-order

Prints wall time, facets, aspects, frequencies and, for the sphere, the RCS error against pi a^2.
Budget in the issue: 360 aspects x 2 frequencies within 5 minutes on a 2-core CPU.
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from rfir_stages.po import icosphere, po_scattered_field
from rfir_stages.po.geometry import facet_table


def subdivide(v, f):
    """Split every triangle into 4 (flat: the surface does not change)."""
    tab = facet_table(v, f)
    m01, m12, m20 = (tab["v0"] + tab["v1"]) / 2, (tab["v1"] + tab["v2"]) / 2, (tab["v2"] + tab["v0"]) / 2
    corners = [tab["v0"], tab["v1"], tab["v2"]]
    tris = [(corners[0], m01, m20), (m01, corners[1], m12), (m20, m12, corners[2]), (m01, m12, m20)]
    vv = np.concatenate([np.stack(t, 1).reshape(-1, 3) for t in tris])
    ff = np.arange(len(vv)).reshape(-1, 3)
    return vv, ff


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--object", choices=["sphere", "car", "h-target", "lego"], default="sphere")
    ap.add_argument("--aspects", type=int, default=360)
    ap.add_argument("--freqs", type=float, nargs="*", default=[2.4e9, 5.8e9])
    ap.add_argument("--wideband", type=int, default=0, help="use N frequencies over 5.72-5.88 GHz instead")
    ap.add_argument("--range", type=float, default=2.0, help="radar range [m]")
    ap.add_argument("--near-field", action="store_true")
    ap.add_argument("--second-order", action="store_true")
    ap.add_argument("--shadow-samples", type=int, default=4)
    a = ap.parse_args()
    if a.object == "sphere":
        radius = 0.25
        v, f = icosphere(radius, 5)
        ref = np.pi * radius**2
    elif a.object == "car":
        from rfir_stages.simulate.scenes import car
        o = car().objects[0]
        v, f = o.vertices, o.faces
        while len(f) < 20000:
            v, f = subdivide(v, f)
        ref = None
    else:
        from rfir_stages.po import scene_mesh
        from rfir_stages.simulate.scenes import build_scene
        v, f, mats, th = scene_mesh(build_scene(a.object))
        ref = None
    freqs = np.linspace(5.72e9, 5.88e9, a.wideband) if a.wideband else np.asarray(a.freqs)
    az = np.linspace(0, 2 * np.pi, a.aspects, endpoint=False)
    el = np.radians(10.0 if a.object in ("sphere", "car") else 0.0)
    tx = a.range * np.stack([np.cos(az) * np.cos(el), np.sin(az) * np.cos(el), np.full_like(az, np.sin(el))], 1)
    refl, thick = ("metal", None) if a.object in ("sphere", "car") else (mats, th)
    t0, c0 = time.perf_counter(), time.process_time()
    s = po_scattered_field(v, f, refl, tx, tx, freqs, near_field=a.near_field, second_order=a.second_order,
                           shadow_samples=a.shadow_samples, face_thickness=thick)
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    sig_db = 10 * np.log10(np.abs(s) ** 2)
    print(f"object={a.object} facets={len(f)} aspects={a.aspects} freqs={len(freqs)} near_field={a.near_field} "
          f"second_order={a.second_order} shadow_samples={a.shadow_samples}")
    print(f"time_s={dt:.1f} (wall)  cpu_s={cpu:.1f} (this process, all threads)  per_aspect_ms={1e3 * dt / a.aspects:.1f}")
    print(f"rcs_dbsm: min {sig_db.min():.2f} median {np.median(sig_db):.2f} max {sig_db.max():.2f}")
    if ref is not None:
        err = sig_db - 10 * np.log10(ref)
        print(f"sphere error vs pi a^2 [dB]: max |err| {np.abs(err).max():.3f} (near field adds range effects)")


if __name__ == "__main__":
    main()
