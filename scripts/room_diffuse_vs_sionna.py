"""The room model's diffuse power against Sionna RT's diffuse paths, both with the simulator's materials.

    python scripts/room_diffuse_vs_sionna.py RF.h5 MEASUREMENTS.h5 --tx 0 --tx 9 [--every 4] [--scattering 0.3]
        [--pattern directive|lambertian] [--samples 30000] [--max-paths 10000000]

RF.h5: an rf-fit of MEASUREMENTS.h5's scene (`rfir simulate classroom`); its geometry and room settings are used,
its materials replaced by the simulator's (ITU-R P.2040 law and slab thickness of every class, scattering
coefficient --scattering for all). The links: every --every-th receiver of transmitter id --tx. Sionna: depth 3,
specular, refraction and diffuse reflection with --pattern (alpha_r 4 for the directive lobe), --samples rays per
transmitter; its paths are split into those with no diffuse interaction (summed coherently) and those with one or
more (summed in power), by how many diffuse and specular interactions they have. Sionna's path buffer
(--max-paths) holds the paths of all receivers of a transmitter; overflowing, it drops paths of both kinds without a
word (1e6 rays at 110 receivers and 1e7 lost 2-3 of every 4 diffuse paths' power and moved the specular sum by
1.4 dB on the mean link): a setting is safe when doubling --max-paths changes nothing (the simulator's 30,000 rays
and 1e7 were checked so, docs/simulate.md "Sionna's path buffer").

Printed per transmitter: the share of Sionna's diffuse power by (diffuse, specular) interactions, the median of the
model's diffuse power over Sionna's first-order diffuse and over all of it (dB), the diffuse share of each side's
total power, and the median and mean |difference| of the specular and total power. A diagnostic, not a stage.
"""
from __future__ import annotations

import argparse
import collections
import math
import tempfile
from pathlib import Path

import numpy as np
import torch

from rfir_core.artifacts import read_artifact
from rfir_core.physics.materials import power_law
from rfir_stages.model.physical import MaterialValues
from rfir_stages.model.room import RoomPredictor
from rfir_stages.simulate.radio_scene import MaterialEffects, load_radio_scene
from rfir_stages.simulate.scenes import build_scene
from rfir_stages.simulate.scene_edits import apply_scene_edits, measurement_scene_edits
from rfir_stages.simulate.truth import true_materials
from room_paths_vs_sionna import DIFFUSE, SPECULAR, solve_paths


def true_values(names: list[str], scene: str, edits: list[str], freq_hz: float, s: float, d: float) -> MaterialValues:
    """The simulator's materials of each class in `names`, scattering coefficient s, conductivity exponent d."""
    t = true_materials(scene, names, freq_hz, edits)
    col = lambda k: torch.tensor([t[n][k] for n in names], dtype=torch.float64)   # noqa: E731
    return MaterialValues(col(2), col(3) / power_law(1.0, d, freq_hz), d, torch.full((len(names),), s, dtype=torch.float64),
                          col(1))


def sionna_split(scene, tx, rx, freq_hz: float, samples: int, max_paths: int) -> tuple[np.ndarray, dict]:
    """(coherent power of the paths without a diffuse interaction [R], {(diffuse, specular) counts: power [R]})."""
    a, tau, valid, inter, _ = solve_paths(scene, tx, rx, 3, samples, max_paths, diffuse=True)
    diffuse: dict = collections.defaultdict(lambda: np.zeros(len(rx)))
    field = np.zeros(len(rx), complex)
    for r in range(len(rx)):
        for p in np.flatnonzero(valid[r]):
            it = inter[:, r, p]
            nd, ns = int((it == DIFFUSE).sum()), int((it == SPECULAR).sum())
            if nd == 0:
                field[r] += a[r, p] * np.exp(-2j * math.pi * freq_hz * tau[r, p])   # paths.a carries no carrier phase
            else:
                diffuse[(nd, ns)][r] += abs(a[r, p]) ** 2
    return np.abs(field) ** 2, dict(diffuse)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("rf", type=Path)
    ap.add_argument("measurements", type=Path)
    ap.add_argument("--tx", type=int, action="append", required=True, help="transmitter id; repeat for more")
    ap.add_argument("--every", type=int, default=4, help="every n-th receiver of each transmitter")
    ap.add_argument("--scattering", type=float, default=0.3, help="S of every material, both sides")
    ap.add_argument("--pattern", default="directive", choices=("directive", "lambertian"))
    ap.add_argument("--samples", type=int, default=30_000)
    ap.add_argument("--max-paths", type=int, default=10_000_000)
    args = ap.parse_args()
    rf = read_artifact(args.rf, "rf")
    meas = read_artifact(args.measurements, "measurements")
    pred = RoomPredictor(rf)
    f = pred.freq_hz
    names = [str(s) for s in np.atleast_1d(rf.free["model@attrs"]["material_names"])]
    scene_name = str(meas.attrs.get("scene", rf.attrs.get("scene", "classroom")))
    edits = measurement_scene_edits(meas)
    mats = true_values(names, scene_name, edits, f, args.scattering, pred.mats.sigma_exponent)
    tx_all, rx_all, tid = np.asarray(meas["tx_pos"]), np.asarray(meas["rx_pos"]), np.asarray(meas["tx_id"])
    spec = apply_scene_edits(build_scene(scene_name), edits)
    db = lambda x: 10 * np.log10(np.maximum(x, 1e-30))   # noqa: E731
    with tempfile.TemporaryDirectory() as tmp:
        scene = load_radio_scene(spec, Path(tmp), f, MaterialEffects(args.scattering, args.pattern, 4))
        for t in args.tx:
            rows = np.flatnonzero(tid == t)[::args.every]
            if not len(rows):
                raise SystemExit(f"{args.measurements}: no transmitter with id {t}")
            tx, rx = tx_all[rows[0]], rx_all[rows]
            with torch.no_grad():
                links = pred.room.links(np.repeat(tx[None], len(rx), 0), rx, np.full(len(rx), f))
                field, model_diffuse = (x.numpy() for x in links.components(mats))
            model_spec = np.abs(field) ** 2
            sionna_spec, parts = sionna_split(scene, tx, rx, f, args.samples, args.max_paths)
            first = parts.get((1, 0), np.zeros(len(rx)))
            total = sum(parts.values())
            print(f"tx {t} at {np.round(tx, 2).tolist()}: {len(rx)} receivers, {args.samples} rays, {args.pattern} lobe")
            print("  Sionna's diffuse power by (diffuse, specular) interactions, median share: " + ", ".join(
                f"{k}: {np.median(parts[k] / total):.3f}" for k in sorted(parts)))
            print(f"  model diffuse / Sionna's first-order diffuse: median {np.median(db(model_diffuse) - db(first)):+.2f} dB; "
                  f"/ all Sionna's diffuse: {np.median(db(model_diffuse) - db(total)):+.2f} dB")
            print(f"  diffuse share of the power: Sionna {np.median(total / (total + sionna_spec)):.3f}, model "
                  f"{np.median(model_diffuse / (model_diffuse + model_spec)):.3f}")
            d_spec, d_all = db(model_spec) - db(sionna_spec), db(model_spec + model_diffuse) - db(sionna_spec + total)
            print(f"  specular: model - Sionna median {np.median(d_spec):+.2f} dB, mean |.| {np.mean(np.abs(d_spec)):.2f}; "
                  f"total: median {np.median(d_all):+.2f} dB, mean |.| {np.mean(np.abs(d_all)):.2f}", flush=True)


if __name__ == "__main__":
    main()
