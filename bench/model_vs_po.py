"""Fidelity of the physical model to physical-optics data: the model with the TRUE materials, no fitting.

    .venv/bin/python bench/model_vs_po.py D/scene.h5 D/ [--range 3] [--step 2] [--lit-threshold 0.2]
                                          [--first-order] [--mesh-visibility] [--aspects 45:65] [--plot out.png]

D/ is an `rfir simulate OBJ D --rcs-backend po` folder (measurements.h5, meshes/labels.json with each
object's ITU material and slab thickness); scene.h5 holds surfels with the same labels (`rfir
mesh-gaussians D/meshes/OBJ_gt.ply -o scene.h5 --spacing S`). Every label gets its object's ITU law
evaluated at each frequency (eps_r, sigma), its thickness and S = 0; the model (rfir_stages.model,
docs/physics.md section 8) predicts every row picked (--range, every --step-th) and the MAE against
the data is printed per frequency and range, with the mean error (model - data).

--first-order: no double bounces in the model; the data then hold both orders, so compare with
data made with `--set simulate.po.second_order=false`. --mesh-visibility: the lit/shadowed state of
each surfel by ray casting the scene's true mesh (an oracle: what the model would give with exact
shadows) instead of tracing the Gaussians. --aspects LO:HI: print the data, the model and their
difference (dB) of every row picked whose aspect lies in [LO, HI] degrees, per frequency.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from rfir_core.artifacts import read_artifact
from rfir_core.physics.materials import itu_law
from rfir_stages.model.physical import MaterialValues, PairSettings, build_pairs, scattered_field
from rfir_stages.model.antenna_patterns import antenna_choice
from rfir_stages.model.links import geometry_from_artifact, make_links, scene_centre
from rfir_stages.model.occlusion import make_provider


class MeshVisibility:
    """Occlusion provider by ray casting a triangle mesh (1 lit, 0 shadowed): the oracle."""

    name = "mesh"

    def __init__(self, geom, vertices, faces, eps_m=1e-5):
        from rfir_stages.po.visibility import Occluder

        self.geom, self.occ, self.eps_m = geom, Occluder(vertices, faces), eps_m

    def segment_transmittance(self, origins, target_ids, margin_m, opacity, t_stop=1e-4):
        p = self.geom.means[target_ids].numpy()
        u = origins.double().numpy() - p
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        return torch.as_tensor(self.occ.unoccluded(p + self.eps_m * u, u).astype(np.float64))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("data")
    ap.add_argument("--range", type=float, default=None, help="only the rows at this range (m)")
    ap.add_argument("--step", type=int, default=1, help="every step-th row")
    ap.add_argument("--lit-threshold", type=float, default=PairSettings.lit_threshold)
    ap.add_argument("--first-order", action="store_true")
    ap.add_argument("--mesh-visibility", action="store_true")
    ap.add_argument("--aspects", default=None, help="LO:HI degrees: print these rows, data and model")
    ap.add_argument("--plot", default=None)
    a = ap.parse_args()
    shown = _aspect_range(a.aspects) if a.aspects else None   # bad input stops here, before the model runs

    data = Path(a.data)
    scene = read_artifact(a.scene, ("scene", "rf"))
    meas = read_artifact(data / "measurements.h5", "measurements")
    objects = {o["name"]: o for o in json.loads((data / "meshes" / "labels.json").read_text())["objects"]}
    names = [str(s) for s in scene.attrs["label_names"]]
    rows = np.arange(len(meas["range_m"]))
    if a.range is not None:
        rows = rows[np.isclose(meas["range_m"], a.range)]
    rows = rows[:: a.step]
    freqs = np.asarray(meas["freq_hz"], float)
    target = np.asarray(meas["path_gain_db"])[rows]
    rng = np.asarray(meas["range_m"])[rows]
    geom = geometry_from_artifact(scene)
    links = make_links(meas["tx_pos"][rows], meas["rx_pos"][rows], freqs, scene_centre(geom), "rcs")
    labels = torch.as_tensor(np.asarray(scene["gaussians/labels"])).long()
    ant = antenna_choice({}, meas, "rcs", str(data / "measurements.h5"))
    if a.mesh_visibility:
        from rfir_stages.po import scene_mesh
        from rfir_stages.simulate.scenes import build_scene

        v, f, _, _ = scene_mesh(build_scene(str(meas.attrs["scene"])))
        provider = MeshVisibility(geom, v, f)
    else:
        provider = make_provider("auto", geom)
    t0 = time.time()
    pairs = build_pairs(geom, links, ant, ant, provider,
                        PairSettings(second_order=not a.first_order, lit_threshold=a.lit_threshold), labels=labels)
    pred = np.zeros_like(target)
    for k, fk in enumerate(freqs):   # each ITU law at this frequency: sigma_1GHz chosen so sigma(f) is exact
        eps, sigma = zip(*(itu_law(objects[n]["radio_material"], fk) for n in names))
        mats = MaterialValues(torch.tensor(np.asarray(eps, float)), torch.tensor(np.asarray(sigma, float) / (fk / 1e9)),
                              1.0, torch.zeros(len(names), dtype=torch.float64),
                              torch.tensor([float(objects[n]["thickness_m"]) for n in names]))
        with torch.no_grad():
            field, diffuse = scattered_field(pairs, labels, mats)
        pred[:, k] = 10 * np.log10(np.maximum((field.abs() ** 2 + diffuse).numpy()[:, k], 1e-30))
    err = pred - target
    print(f"{a.scene}: {len(rows)} rows, {geom.num} surfels, {time.time() - t0:.0f} s; MAE per frequency "
          f"{np.round(np.abs(err).mean(0), 2)} dB, mean error {np.round(err.mean(0), 2)} dB "
          f"({', '.join(f'{f / 1e9:g}' for f in freqs)} GHz)")
    for r in np.unique(rng):
        m = rng == r
        print(f"  range {r:g} m: MAE {np.round(np.abs(err[m]).mean(0), 2)} dB, mean {np.round(err[m].mean(0), 2)} dB")
    if shown:
        lo, hi = shown
        asp = np.degrees(np.asarray(meas["aspect_rad"])[rows])
        print("  aspect  range  " + "  ".join(f"{f / 1e9:g} GHz: data  model  diff" for f in freqs))
        for i in np.flatnonzero((asp >= lo - 1e-9) & (asp <= hi + 1e-9)):
            print(f"  {asp[i]:6.1f} {rng[i]:6g}  " + "  ".join(
                f"{target[i, k]:15.1f} {pred[i, k]:6.1f} {err[i, k]:5.1f}" for k in range(len(freqs))))
    if a.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        r0 = np.unique(rng)[len(np.unique(rng)) // 2]
        m = rng == r0
        asp = np.degrees(np.asarray(meas["aspect_rad"])[rows])[m]
        fig, axes = plt.subplots(len(freqs), 1, figsize=(12, 3.5 * len(freqs)), squeeze=False)
        for k, ax in enumerate(axes[:, 0]):
            ax.plot(asp, target[m, k], "k-", lw=1, label="physical-optics data")
            ax.plot(asp, pred[m, k], "r-", lw=1, label="model, true materials")
            ax.set_title(f"{freqs[k] / 1e9:g} GHz, {r0:g} m: MAE {np.abs(err[m, k]).mean():.2f} dB")
            ax.set_xlabel("aspect [deg]")
            ax.set_ylabel("path gain [dB]")
            ax.legend()
        fig.tight_layout()
        fig.savefig(a.plot, dpi=80)


def _aspect_range(text: str) -> tuple[float, float]:
    try:
        lo, hi = (float(x) for x in text.split(":"))
    except ValueError:
        raise SystemExit(f"model_vs_po.py: --aspects {text!r}: expected LO:HI in degrees, e.g. 45:65") from None
    return lo, hi


if __name__ == "__main__":
    main()
