"""The room model's specular paths against Sionna RT's on a scene `rfir simulate` builds, link by link.

    python scripts/room_paths_vs_sionna.py SCENE.h5 --scene flat --tx 2,2,2.2 --tx 7,5.5,2.2 [--depth 3]
        [--grid 0.6] [--rx-height 1.0] [--samples 1000000] [--max-paths 10000000] [--diffuse S] [--json OUT.json]

SCENE.h5: surfels of the scene's true mesh (`rfir mesh-gaussians SIM/meshes/flat_gt.ply -o SCENE.h5 ...`,
labels naming the simulator's objects). Both sides get the simulator's own materials (ITU-R P.2040 law and
slab thickness of every object) and nothing is fitted: Sionna with specular reflection and refraction up to
`--depth` interactions, no diffraction, the coherent sum of its specular paths (with `--diffuse S`, solved
with diffuse reflection on as rfir simulate does and its diffuse paths left out); the room model
(rfir_stages.model.room_paths) with reflections up to order min(depth, 3) and at most `depth` interactions per
path, its default patches (tiles) and area thresholds, no diffuse term. Receivers: a grid at --rx-height,
clear of every object's bounding box (a wall's plane included) by 5 cm.

Printed per transmitter and overall: the median and mean |difference| of the received power (dB, model minus
Sionna); the share of each link's Sionna power in paths the model does not have (matched by the sequence of
interactions: reflection or crossing, and the object), and the share of the model's power in paths Sionna
does not have, by number of interactions and by the objects involved. A diagnostic, not a stage.
"""
from __future__ import annotations

import argparse
import collections
import json
import math
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from rfir_core.artifacts import read_artifact
from rfir_core.physics.materials import itu_law, permittivity
from rfir_stages.model.room_paths import THIRD_ORDER_SMALL_REFLECTIONS, build_patch_set, trace_room_paths
from rfir_stages.model.surfels import surfel_areas
from rfir_stages.model.occlusion import FrozenGeometry, make_provider
from rfir_stages.simulate.radio_scene import MaterialEffects, load_radio_scene, set_devices
from rfir_stages.simulate.rssi import clear_of_objects
from rfir_stages.simulate.scenes import build_scene
from rfir_stages.simulate.truth import object_class
from rfir_stages.simulate.solve import PhysicsEffects

SPECULAR, DIFFUSE, REFRACTION = 1, 2, 4        # sionna.rt.InteractionType values
CLEARANCE_M = 0.05


def receivers(spec, grid_m: float, height_m: float) -> np.ndarray:
    """[R, 3] grid points inside the scene's bounds, clear of every object's bounding box (a wall's is its plane)."""
    lo, hi = spec.bounds
    xs, ys = np.meshgrid(np.arange(lo[0] + grid_m / 2, hi[0], grid_m), np.arange(lo[1] + grid_m / 2, hi[1], grid_m))
    pts = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, height_m)], 1)
    return pts[clear_of_objects(spec, pts, CLEARANCE_M)]


def kind_of(seq: tuple) -> str:
    """The object classes a path involves (window_03 -> window), sorted; "direct" for none."""
    return "+".join(sorted({object_class(s.split(":", 1)[1]) for s in seq})) or "direct"


def solve_paths(scene, tx, rx, depth: int, samples: int, max_paths: int, diffuse: bool):
    """Sionna's paths from one transmitter tx [3] to receivers rx [R, 3] (specular reflection and refraction up to
    `depth` interactions, diffuse reflection when asked, no diffraction): (amplitudes [R, P] complex without the
    carrier phase, delays [R, P] s, valid [R, P] bool, interaction types [depth, R, P], object ids [depth, R, P])."""
    import sionna.rt as rt

    set_devices(scene, tx[None], rx)
    solver = rt.PathSolver()
    solver.loop_mode = "evaluated"
    phys = PhysicsEffects(max_depth=depth, diffuse=diffuse, refraction=True, samples_per_src=samples,
                          max_num_paths_per_src=max_paths, combine="coherent")
    paths = solver(scene, **phys.solver_kwargs(los=True))
    a = (np.asarray(paths.a[0].numpy()) + 1j * np.asarray(paths.a[1].numpy()))[:, 0, 0, 0, :]
    tau = np.asarray(paths.tau.numpy())[:, 0, :]
    valid = np.asarray(paths.valid.numpy()).reshape(a.shape)
    return (a, tau, valid, np.asarray(paths.interactions.numpy())[:, :, 0, :],
            np.asarray(paths.objects.numpy())[:, :, 0, :])


def sionna_paths(scene, tx, rx, freq: float, depth: int, samples: int, max_paths: int, diffuse: bool = False) -> list[dict]:
    """Per receiver {interaction sequence: power} of Sionna's specular / refracted paths, and their coherent power
    (diffuse: solved with diffuse reflection on, as rfir simulate does, and its diffuse paths left out)."""
    a, tau, valid, inter, objs = solve_paths(scene, tx, rx, depth, samples, max_paths, diffuse)
    names = {obj.object_id: name for name, obj in scene.objects.items()}
    out = []
    for r in range(len(rx)):
        seqs: dict = collections.defaultdict(float)
        field = 0j
        for p in np.flatnonzero(valid[r]):
            if np.any(inter[:, r, p] == DIFFUSE):
                continue
            seq = tuple(("R" if inter[k, r, p] == SPECULAR else "T") + ":" + names.get(int(objs[k, r, p]), "?")
                        for k in range(depth) if inter[k, r, p] in (SPECULAR, REFRACTION))
            seqs[seq] += float(abs(a[r, p])) ** 2
            field += a[r, p] * np.exp(-2j * math.pi * freq * tau[r, p])   # paths.a carries no carrier phase
        out.append({"paths": dict(seqs), "power": float(abs(field)) ** 2})
    return out


def model_paths(tx, rx, freq_hz, patches, provider, depth: int, eta, thickness, names, s: float = 0.0,
                third_order_small: int = 0) -> list[dict]:
    """The same per receiver for the room model with the true materials (eta, thickness per patch; scattering
    coefficient s of every material; third_order_small: the room model's third_order_small_reflections)."""
    p = trace_room_paths(np.repeat(tx[None], len(rx), 0), rx, np.full(len(rx), freq_hz), patches, provider,
                         polarisation="V", max_order=min(depth, 3), max_interactions=depth,
                         third_order_small_reflections=third_order_small)
    zero_s = torch.full((patches.num,), float(s), dtype=torch.float64)
    total = p.field(eta, thickness, zero_s).numpy()
    per = replace(p, link=torch.arange(p.num), num_links=p.num, freq_hz=p.freq_hz[p.link])  # one "link" per path
    power = np.abs(per.field(eta, thickness, zero_s).numpy()) ** 2
    link, kind, patch = p.link.numpy(), p.kind.numpy(), p.patch.numpy()
    out = [{"paths": collections.defaultdict(float), "power": abs(total[r]) ** 2} for r in range(len(rx))]
    for q in range(p.num):
        seq = tuple(("R" if kind[q, k] == 1 else "T") + ":" + names[int(patches.label[patch[q, k]])]
                    for k in range(kind.shape[1]) if kind[q, k] > 0)
        out[link[q]]["paths"][seq] += float(power[q])
    return out


def true_materials(scene_h5: Path, spec, freq_hz: float):
    """The room model's patches of SCENE.h5's surfels (default extents) with the simulator's materials of `spec`:
    (patches, tracer provider, eta [P, 1] complex relative permittivity and thickness [P] m per patch, label
    names)."""
    scene_art = read_artifact(scene_h5, "scene")
    g = {k: np.asarray(scene_art.data["gaussians/" + k]) for k in ("means", "log_scales", "rotations", "normals", "labels")}
    label_names = [str(s) for s in scene_art.attrs["label_names"]]
    by_name = {o.name: o for o in spec.objects}
    geom = FrozenGeometry(*(torch.as_tensor(g[k]).double() for k in ("means", "log_scales", "rotations", "normals")))
    areas = surfel_areas(geom.means, geom.log_scales, geom.rotations, geom.normals)
    patches = build_patch_set(geom, areas, torch.as_tensor(g["labels"], dtype=torch.int64), 0.01, extent="tiles")
    eta_l = [complex(permittivity(*(float(np.asarray(x).reshape(-1)[0])
                                    for x in itu_law(by_name[n].radio_material, freq_hz)), freq_hz))
             for n in label_names]
    lab = torch.as_tensor(patches.label)
    eta = torch.as_tensor(np.array(eta_l))[lab][:, None]
    thickness = torch.as_tensor(np.array([by_name[n].thickness_m for n in label_names]))[lab]
    return patches, make_provider("auto", geom), eta, thickness, label_names


def compare(model: list[dict], sionna: list[dict]) -> dict:
    """Differences in dB and unmatched power shares over links with power on both sides."""
    diff, missing, extra = [], collections.Counter(), collections.Counter()
    miss_n, extra_n = collections.Counter(), collections.Counter()
    n = 0
    for m, s in zip(model, sionna):
        if not (m["power"] > 1e-18 and s["power"] > 1e-18):
            continue
        n += 1
        diff.append(10 * math.log10(m["power"] / s["power"]))
        s_tot, m_tot = sum(s["paths"].values()), sum(m["paths"].values())
        for seq, pw in s["paths"].items():
            if seq not in m["paths"]:
                missing[kind_of(seq)] += pw / s_tot
                miss_n[len(seq)] += pw / s_tot
        for seq, pw in m["paths"].items():
            if seq not in s["paths"]:
                extra[kind_of(seq)] += pw / m_tot
                extra_n[len(seq)] += pw / m_tot
    d = np.abs(np.asarray(diff))
    return {"links": n, "median_abs_db": float(np.median(d)), "mean_abs_db": float(d.mean()),
            "sionna_power_missing_in_model": sum(missing.values()) / n,
            "model_power_missing_in_sionna": sum(extra.values()) / n,
            "missing_by_interactions": {k: v / n for k, v in sorted(miss_n.items())},
            "extra_by_interactions": {k: v / n for k, v in sorted(extra_n.items())},
            "missing_top": {k: v / n for k, v in missing.most_common(8)},
            "extra_top": {k: v / n for k, v in extra.most_common(8)}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene_h5", type=Path)
    ap.add_argument("--scene", required=True, help="the simulator's scene the surfels tile (rfir simulate NAME)")
    ap.add_argument("--tx", action="append", required=True, help="transmitter x,y,z [m]; repeat for more")
    ap.add_argument("--depth", type=int, default=3)
    ap.add_argument("--grid", type=float, default=0.6)
    ap.add_argument("--rx-height", type=float, default=1.0)
    ap.add_argument("--freq-hz", type=float, default=2.4e9)
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--max-paths", type=int, default=10_000_000, help="Sionna's max_num_paths_per_src")
    ap.add_argument("--diffuse", type=float, default=0.0, metavar="S",
                    help="solve with diffuse reflection on, scattering coefficient S on every material (rfir "
                         "simulate: 0.3, directive, alpha_r 4), its diffuse paths left out; the model's reflections "
                         "get the same S")
    ap.add_argument("--third-order-small", type=int, default=THIRD_ORDER_SMALL_REFLECTIONS,
                    help="the room model's third_order_small_reflections ([rf_fit.room])")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    spec = build_scene(args.scene)
    f = args.freq_hz
    patches, provider, eta, thickness, label_names = true_materials(args.scene_h5, spec, f)
    rx = receivers(spec, args.grid, args.rx_height)
    print(f"{len(rx)} receivers, {patches.num} patches; Sionna and the room model at depth {args.depth}, "
          "specular and refraction, no diffuse, true materials")
    all_m, all_s, report = [], [], {}
    with tempfile.TemporaryDirectory() as tmp:
        scene = load_radio_scene(spec, Path(tmp), f, MaterialEffects(args.diffuse, "directive", 4))
        for text in args.tx:
            tx = np.array([float(v) for v in text.split(",")])
            s = sionna_paths(scene, tx, rx, f, args.depth, args.samples, args.max_paths, args.diffuse > 0)
            m = model_paths(tx, rx, f, patches, provider, args.depth, eta, thickness, label_names, args.diffuse,
                            args.third_order_small)
            report[text] = compare(m, s)
            all_m += m
            all_s += s
            r = report[text]
            print(f"tx {text}: {r['links']} links, |model - Sionna| median {r['median_abs_db']:.2f} dB, mean "
                  f"{r['mean_abs_db']:.2f} dB; Sionna's power in paths the model lacks {r['sionna_power_missing_in_model']:.1%}, "
                  f"the model's in paths Sionna lacks {r['model_power_missing_in_sionna']:.1%}", flush=True)
    report["all"] = compare(all_m, all_s)
    r = report["all"]
    print(f"all: {r['links']} links, median {r['median_abs_db']:.2f} dB, mean {r['mean_abs_db']:.2f} dB; "
          f"missing in the model {r['sionna_power_missing_in_model']:.1%} "
          f"(by interactions {', '.join(f'{k}: {v:.1%}' for k, v in r['missing_by_interactions'].items())}), "
          f"missing in Sionna {r['model_power_missing_in_sionna']:.1%} "
          f"(by interactions {', '.join(f'{k}: {v:.1%}' for k, v in r['extra_by_interactions'].items())})")
    print("  the model lacks: " + "; ".join(f"{k} {v:.1%}" for k, v in r["missing_top"].items()))
    print("  Sionna lacks:    " + "; ".join(f"{k} {v:.1%}" for k, v in r["extra_top"].items()))
    if args.json:
        args.json.write_text(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
