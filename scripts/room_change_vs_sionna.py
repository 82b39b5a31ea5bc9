"""An edit's change in received power, the room model's against Sionna RT's, both with the simulator's materials.

    python scripts/room_change_vs_sionna.py SCENE.h5 EDITED.h5 --scene classroom --scene-edit EDIT
        --measurements BEFORE.h5 --edited-measurements AFTER.h5 --tx-index 0 [--tx-index 7 ...]
        [--samples 1000000] [--json OUT.json]

SCENE.h5 / EDITED.h5: surfels of the scene's true mesh before and after the edit (`rfir mesh-gaussians
SIM/meshes/classroom_gt.ply ...` of the unedited and of the edited simulation); EDIT: the simulator's scene edit
(`rfir simulate --scene-edit`). The links are the measurement's: every receiver of the transmitters picked by
index (in the order of numpy.unique over the file's transmitter positions). Both sides as in
scripts/room_paths_vs_sionna.py (specular reflection and refraction up to three interactions, no diffuse, the
model with its default patches and the simulator's own materials, nothing fitted), solved on the unedited and on
the edited scene. Printed: the model's level against Sionna's (median and mean |difference|, dB, both scenes),
and the rank correlation (Spearman) of the change (edited - unedited, dB) between the model, Sionna and the two
measurement files (what the simulator recorded with its own sampling and diffuse scattering). A diagnostic, not
a stage.
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

import numpy as np
from scipy.stats import spearmanr

from room_paths_vs_sionna import model_paths, sionna_paths, true_materials
from rfir_core.artifacts import read_artifact
from rfir_stages.simulate.radio_scene import MaterialEffects, load_radio_scene
from rfir_stages.simulate.scene_edits import apply_scene_edits
from rfir_stages.simulate.scenes import build_scene


def powers(scene_h5: Path, scene: str, edits: list[str], tx_all, rx_all, picks, freq: float, samples: int):
    """(model [L], Sionna [L]) coherent received power of the picked transmitters' links, in the links' order."""
    spec = build_scene(scene)
    if edits:
        apply_scene_edits(spec, edits)
    patches, provider, eta, thickness, names = true_materials(scene_h5, spec, freq)
    model, sionna = [], []
    with tempfile.TemporaryDirectory() as tmp:
        radio = load_radio_scene(spec, Path(tmp), freq, MaterialEffects(0.0, "directive", 4))
        for tx in picks:
            rows = np.all(tx_all == tx, axis=1)
            s = sionna_paths(radio, tx, rx_all[rows], freq, 3, samples, 10_000_000)
            m = model_paths(tx, rx_all[rows], freq, patches, provider, 3, eta, thickness, names, 0.0, 1)
            sionna += [x["power"] for x in s]
            model += [x["power"] for x in m]
            print(f"{scene_h5.name}: tx {np.round(tx, 2).tolist()}, {int(rows.sum())} links", flush=True)
    return np.asarray(model), np.asarray(sionna)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene_h5", type=Path)
    ap.add_argument("edited_h5", type=Path)
    ap.add_argument("--scene", required=True)
    ap.add_argument("--scene-edit", action="append", required=True, help="the simulator's edit; repeat for more")
    ap.add_argument("--measurements", type=Path, required=True)
    ap.add_argument("--edited-measurements", type=Path, required=True)
    ap.add_argument("--tx-index", type=int, action="append", required=True)
    ap.add_argument("--samples", type=int, default=1_000_000)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    before, after = (read_artifact(p, "measurements") for p in (args.measurements, args.edited_measurements))
    tx_all, rx_all = np.asarray(before["tx_pos"]), np.asarray(before["rx_pos"])
    if not (np.array_equal(tx_all, np.asarray(after["tx_pos"])) and np.array_equal(rx_all, np.asarray(after["rx_pos"]))):
        raise SystemExit(f"{args.edited_measurements}: its links differ from {args.measurements}'s")
    freq = float(np.asarray(before["freq_hz"]).reshape(-1)[0])
    picks = np.unique(tx_all, axis=0)[args.tx_index]
    rows = np.concatenate([np.flatnonzero(np.all(tx_all == t, axis=1)) for t in picks])
    m0, s0 = powers(args.scene_h5, args.scene, [], tx_all, rx_all, picks, freq, args.samples)
    m1, s1 = powers(args.edited_h5, args.scene, args.scene_edit, tx_all, rx_all, picks, freq, args.samples)
    data = np.asarray(after["path_gain_db"])[rows, 0] - np.asarray(before["path_gain_db"])[rows, 0]
    model, sionna = 10 * np.log10(m1 / m0), 10 * np.log10(s1 / s0)
    level = np.abs(10 * np.log10(np.concatenate([m0, m1]) / np.concatenate([s0, s1])))
    out = {"links": int(len(rows)), "level_median_abs_db": float(np.median(level)), "level_mean_abs_db": float(level.mean()),
           "change_rank_model_sionna": float(spearmanr(model, sionna)[0]),
           "change_rank_model_data": float(spearmanr(model, data)[0]),
           "change_rank_sionna_data": float(spearmanr(sionna, data)[0])}
    print(f"{out['links']} links; model - Sionna: median {out['level_median_abs_db']:.2f} dB, mean "
          f"{out['level_mean_abs_db']:.2f} dB (both scenes); change rank correlation model/Sionna "
          f"{out['change_rank_model_sionna']:.3f}, model/data {out['change_rank_model_data']:.3f}, "
          f"Sionna/data {out['change_rank_sionna_data']:.3f}")
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
