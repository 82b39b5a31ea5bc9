"""The "traditional ray tracing" baselines (issues 11 and 63): Sionna RT on a mesh with ITU materials,
predicting the links of an RSSI measurement file; scored on its test split.

One guessed material for a whole mesh (a mesh from photos carries no labels):

    python scripts/baseline_raytrace.py MESH.ply MEASUREMENTS.h5 --material concrete --results results/NAME.json

A labelled mesh (e.g. `rfir import floorplan`'s room.ply with labels.json beside it) on a survey whose transmit
power and antenna gains are unknown, in two steps:

    python scripts/baseline_raytrace.py sweep MESH.ply MEASUREMENTS.h5 --out SWEEP.npz
        [--wall-materials concrete,brick,plasterboard,wood,glass,metal] [--wall-thickness plan,0.1,0.3]
    python scripts/baseline_raytrace.py score SWEEP.npz MEASUREMENTS.h5 --results results/NAME.json

`sweep` predicts every link of MEASUREMENTS with Sionna RT once per candidate material set: first the
materials and slab thicknesses labels.json names per label ("ITU materials"), then every wall material of
`--wall-materials` with every wall thickness of `--wall-thickness` ("plan": each wall's own thickness from
labels.json; a number: that thickness, m, for every wall). Floor and ceiling (labels named floor* / ceiling*)
keep their labelled material. Devices are matched by their ids, of any form (integers with gaps, strings);
the side with fewer devices is solved as Sionna's transmitters (reciprocity; one solve per device).
`score` reads the sweep and one protocol's split (the file's split column: 1 = test):
- "Sionna RT (ITU)": the labelled materials' path gain plus one system gain, the mean residual of the
  training links (it stands for the unknown transmit power and antenna gains);
- "Sionna RT calibrated": the candidate whose training MAE (after its own system gain) is lowest.
Both are scored on the test links. The scoring is numpy only (`fit_system_gain`, `choose_candidate`).

Sionna settings: `rfir simulate`'s rssi physics (configs/simulate.toml). A baseline, not a stage: it reads
and writes no artifact other than its JSON (and the sweep's npz).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

NO_PATH_DB = -240.0        # predictions at or below: no path found (simulate floors power at -250 dB)
WALL_MATERIALS = "concrete,brick,plasterboard,wood,glass,metal"
WALL_THICKNESS = "plan,0.1,0.3"


# --------------------------------------------------------------------------------------------
# devices and scoring (numpy only)
# --------------------------------------------------------------------------------------------
def device_table(ids, positions, what: str, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distinct devices of a link list: (ids [N] as strings, positions [N, 3] m, each row's device index [L]).

    ids [L]: any form (integers with gaps, strings); positions [L, 3] m. A device whose rows disagree
    on its position by more than 1 mm is an error naming the file."""
    keys = np.asarray([str(v) for v in np.asarray(ids).ravel()])
    pos = np.asarray(positions, np.float64).reshape(-1, 3)
    if keys.size != len(pos):
        raise ValueError(f"{where}: {keys.size} {what} ids for {len(pos)} positions")
    names, index = np.unique(keys, return_inverse=True)
    first = np.zeros(len(names), np.int64)
    first[index[::-1]] = np.arange(len(keys))[::-1]           # first row of each device
    table = pos[first]
    off = np.abs(pos - table[index]).max(1) if len(pos) else np.zeros(0)
    if np.any(off > 1e-3):
        bad = str(names[index[int(np.argmax(off))]])
        raise ValueError(f"{where}: {what} {bad!r} is at more than one position ({off.max():.3f} m apart)")
    return names, table, index


def fit_system_gain(pred_db: np.ndarray, meas_db: np.ndarray, train: np.ndarray) -> float:
    """One gain, dB: the mean of measured - predicted over the training rows that have a path.

    pred_db, meas_db [L] dB; train [L] bool. The unknown transmit power and antenna gains of a survey
    are one constant in dB; its least-squares estimate is the mean residual."""
    use = np.asarray(train, bool) & (np.asarray(pred_db) > NO_PATH_DB)
    if not use.any():
        raise ValueError("no training link with a predicted path: the system gain cannot be fitted")
    return float(np.mean(np.asarray(meas_db)[use] - np.asarray(pred_db)[use]))


def score(pred_db: np.ndarray, meas_db: np.ndarray, train: np.ndarray, test: np.ndarray) -> dict:
    """The system gain fitted on `train`, MAE dB on train and test rows (pred_db, meas_db [L] dB)."""
    gain = fit_system_gain(pred_db, meas_db, train)
    err = np.abs(np.asarray(pred_db) + gain - np.asarray(meas_db))
    return {"system_gain_db": gain, "mae_train_db": float(err[train].mean()), "mae_db": float(err[test].mean()),
            "rmse_db": float(np.sqrt(np.mean(err[test] ** 2)))}


def choose_candidate(preds_db: np.ndarray, meas_db: np.ndarray, train: np.ndarray) -> tuple[int, np.ndarray]:
    """(index of the best candidate, training MAE per candidate [K] dB): preds_db [K, L] dB, each
    candidate with its own system gain; ties go to the earlier candidate."""
    maes = np.array([score(p, meas_db, train, train)["mae_train_db"] for p in np.asarray(preds_db)])
    return int(np.argmin(maes)), maes


# --------------------------------------------------------------------------------------------
# candidates and Sionna
# --------------------------------------------------------------------------------------------
def is_wall(name: str) -> bool:
    """Every label but the floor and the ceiling (`rfir import floorplan` names them floor*, ceiling*)."""
    return not (name.startswith("floor") or name.startswith("ceiling"))


def candidates(labels: list[dict], wall_materials: list[str], wall_thickness: list[str]) -> list[dict]:
    """Material sets to solve: the labelled one first ("labels"), then each wall material x thickness.

    labels: labels.json objects (label, name, radio_material, thickness_m). Returns dicts with name,
    wall_material, wall_thickness and per-label (material, thickness m); duplicates of an earlier set
    (e.g. the labelled set itself) are dropped, and metal gets one thickness (a metal slab is opaque)."""
    base = {int(o["label"]): (str(o["radio_material"]), float(o["thickness_m"])) for o in labels}
    out = [{"name": "labels", "wall_material": "labels", "wall_thickness": "plan", "materials": base}]
    seen = {tuple(sorted(base.items()))}
    for mat in wall_materials:
        for th in wall_thickness[:1] if mat == "metal" else wall_thickness:
            mats = {int(o["label"]): ((mat, float(o["thickness_m"]) if th == "plan" else float(th))
                                      if is_wall(str(o["name"])) else base[int(o["label"])]) for o in labels}
            key = tuple(sorted(mats.items()))
            if key in seen:
                continue
            seen.add(key)
            out.append({"name": f"walls {mat} {th if th == 'plan' else f'{float(th):g} m'}", "wall_material": mat,
                        "wall_thickness": th, "materials": mats})
    return out


def _itu(material: str, freq_hz: float) -> tuple[float, float]:
    """(eps_r, sigma S/m) of an ITU material at freq_hz, from Sionna's ITU-R P.2040 table."""
    import mitsuba as mi

    from rfir_stages.simulate.radio_scene import set_variant

    set_variant()
    from sionna.rt.radio_materials.itu import itu_material

    try:
        eps, sigma = itu_material(material, mi.Float(freq_hz))
    except ValueError as exc:      # Sionna's own wording for an unknown name
        raise ValueError(f"material {material!r}: not an ITU material Sionna knows ({exc})") from None
    return float(eps[0]), float(sigma[0])


class LabelMaterials:
    """One Sionna RadioMaterial per label whose (eps_r, sigma, thickness) are opaque Dr.Jit values, so a new
    candidate changes values and not the compiled kernels."""

    def __init__(self, scene, object_of_label: dict[int, str], effects):
        import sionna.rt as rt

        from rfir_stages.simulate.radio_scene import apply_material_effects

        self.mats = {}
        for label, obj in object_of_label.items():
            mat = rt.RadioMaterial(f"material-{label}", thickness=0.1, relative_permittivity=2.0, conductivity=0.01)
            scene.objects[obj].radio_material = mat
            self.mats[label] = mat
        apply_material_effects(scene, effects)   # the simulator's scattering coefficient and pattern

    def set(self, materials: dict[int, tuple[str, float]], freq_hz: float) -> None:
        import drjit as dr
        import mitsuba as mi

        for label, (name, thick) in materials.items():
            eps, sigma = _itu(name, freq_hz)
            v = [mi.Float(eps), mi.Float(sigma), mi.Float(thick)]
            dr.make_opaque(*v)
            mat = self.mats[label]
            mat.relative_permittivity, mat.conductivity, mat.thickness = v


def read_labels(mesh_path: Path) -> tuple[object, list[dict]]:
    """(mesh, labels.json objects) of a labelled PLY; an error naming the file when it has no labels."""
    from rfir_stages.geom.mesh_io import read_ply_mesh

    mesh = read_ply_mesh(mesh_path)
    path = Path(mesh_path).parent / "labels.json"
    if mesh.labels is None or not path.is_file():
        raise ValueError(f"{mesh_path}: no face labels or no labels.json beside it (sweep needs a labelled mesh)")
    objects = json.loads(path.read_text()).get("objects", [])
    missing = sorted(set(np.unique(mesh.labels).tolist()) - {int(o["label"]) for o in objects})
    if missing:
        raise ValueError(f"{path}: labels {missing} of the mesh are not described")
    return mesh, [o for o in objects if np.any(mesh.labels == int(o["label"]))]


def label_spec(mesh, labels: list[dict]):
    """A SceneSpec with one object per label (its faces, vertices re-indexed)."""
    from rfir_stages.simulate.scenes import SceneObject, SceneSpec

    objects = []
    for k, o in enumerate(labels):
        faces = np.asarray(mesh.faces)[mesh.labels == int(o["label"])]
        used, inv = np.unique(faces, return_inverse=True)
        objects.append(SceneObject(f"label-{int(o['label'])}", k, np.asarray(mesh.vertices, np.float64)[used],
                                   inv.reshape(-1, 3).astype(np.int32), str(o["radio_material"]), "plaster",
                                   (0.8, 0.8, 0.8), float(o["thickness_m"])))
    v = np.asarray(mesh.vertices, np.float64)
    return SceneSpec("labelled", "room", objects, np.stack([v.min(0), v.max(0)]))


def sweep(mesh_path, meas_path, out_path, wall_materials: list[str], wall_thickness: list[str],
          say=print) -> dict:
    """Solve every candidate (`candidates`) for every link of the measurements; writes out_path (npz):
    pred_db [K, A, B] dB between devices a_ids [A] and b_ids [B] (a = transmitters of the file), their
    positions, and the candidates as JSON."""
    from rfir_core.artifacts import read_artifact
    from rfir_core.progress import NullProgress
    from rfir_stages.simulate.radio_scene import load_radio_scene
    from rfir_stages.simulate.rssi import simulate_rssi
    from rfir_stages.simulate.settings import parse_settings

    t0 = time.time()
    for th in wall_thickness:
        if th != "plan" and not float(th) > 0:
            raise ValueError(f"--wall-thickness {th!r}: 'plan' or a thickness > 0 m")
    meas = read_artifact(meas_path, "measurements")
    tx_ids, tx, _ = device_table(meas["tx_id"], meas["tx_pos"], "transmitter", str(meas_path))
    rx_ids, rx, _ = device_table(meas["rx_id"], meas["rx_pos"], "receiver", str(meas_path))
    freq = float(np.asarray(meas["freq_hz"], np.float64)[0])
    for m in wall_materials:
        _itu(m, freq)                                   # an unknown material fails before any solve
    mesh, labels = read_labels(Path(mesh_path))
    cands = candidates(labels, wall_materials, wall_thickness)
    settings = parse_settings(None)
    physics, effects = settings.physics_for("rssi"), settings.material_effects()
    swap = len(rx) < len(tx)                           # solve from the side with fewer devices
    src, dst = (rx, tx) if swap else (tx, rx)
    with tempfile.TemporaryDirectory(prefix="rfir-raytrace-") as tmp:   # the scene's XML + PLY, read at load
        scene = load_radio_scene(label_spec(mesh, labels), Path(tmp), freq, effects)
    mats = LabelMaterials(scene, {int(o["label"]): f"label-{int(o['label'])}" for o in labels}, effects)
    say(f"sweep: {len(cands)} material sets, {len(src)} sources x {len(dst)} targets"
        + (" (receivers solved as sources: reciprocity)" if swap else "")
        + f", depth {physics.max_depth}, {physics.samples_per_src} rays per source, {freq / 1e9:g} GHz")
    pred = np.zeros((len(cands), len(tx), len(rx)))
    solve_s, cap_hits = [], 0
    for k, c in enumerate(cands):
        mats.set(c["materials"], freq)
        t = time.time()
        _, power, _, _, _, hits = simulate_rssi(scene, src, dst, [freq], physics, NullProgress(), c["name"])
        solve_s.append(time.time() - t)
        cap_hits += int(hits)
        db = 10 * np.log10(np.maximum(power[:, 0], 1e-25)).reshape(len(src), len(dst))   # rows source-major
        pred[k] = db.T if swap else db
        say(f"sweep: {k + 1}/{len(cands)} {c['name']}: {solve_s[-1]:.0f} s")
    info = {"mesh": str(mesh_path), "measurements": str(meas_path), "freq_hz": freq, "reciprocity_swap": swap,
            "physics": {"max_depth": physics.max_depth, "samples_per_src": physics.samples_per_src,
                        "max_num_paths_per_src": physics.max_num_paths_per_src, "diffuse": physics.diffuse,
                        "refraction": physics.refraction, "diffraction": physics.diffraction,
                        "combine": physics.combine, "scattering_coefficient": effects.scattering_coefficient,
                        "scattering_pattern": effects.scattering_pattern},
            "candidates": [{k: v for k, v in c.items() if k != "materials"}
                           | {"materials": {str(lbl): list(m) for lbl, m in c["materials"].items()}} for c in cands],
            "label_names": {str(o["label"]): o["name"] for o in labels},
            "solve_s": solve_s, "path_buffer_cap_hits": cap_hits, "wall_time_s": time.time() - t0}
    out_path = Path(out_path)
    out_path.parent.mkdir(parents=True, exist_ok=True)
    tmp = out_path.with_name(out_path.name + ".tmp.npz")
    np.savez(tmp, pred_db=pred, tx_ids=tx_ids, rx_ids=rx_ids, tx_pos=tx, rx_pos=rx, info=json.dumps(info))
    tmp.replace(out_path)
    return info


def link_predictions(sweep_npz, meas, where: str) -> tuple[np.ndarray, dict]:
    """(pred_db [K, L] dB for the file's rows, sweep info): rows matched to the sweep's devices by id, positions
    checked (1 mm)."""
    with np.load(sweep_npz) as z:
        pred, tx_ids, rx_ids = z["pred_db"], z["tx_ids"].astype(str), z["rx_ids"].astype(str)
        tx_pos, rx_pos, info = z["tx_pos"], z["rx_pos"], json.loads(str(z["info"]))
    cols = []
    for what, ids_key, pos_key, known, known_pos in (("transmitter", "tx_id", "tx_pos", tx_ids, tx_pos),
                                                     ("receiver", "rx_id", "rx_pos", rx_ids, rx_pos)):
        names, pos, index = device_table(meas[ids_key], meas[pos_key], what, where)
        at = {n: i for i, n in enumerate(known)}
        absent = [str(n) for n in names if n not in at]
        if absent:
            raise ValueError(f"{where}: {what}s {absent[:5]} are not in the sweep {sweep_npz}")
        j = np.array([at[n] for n in names], np.int64)
        if np.any(np.abs(known_pos[j] - pos).max(1) > 1e-3):
            raise ValueError(f"{where}: {what} positions differ from the sweep {sweep_npz}'s")
        cols.append(j[index])
    return pred[:, cols[0], cols[1]], info


def score_sweep(sweep_npz, meas_path, results_path) -> dict:
    """Score the labelled materials (+ system gain) and the calibrated choice on the file's split; writes JSON."""
    from rfir_core.artifacts import read_artifact

    t0 = time.time()
    meas = read_artifact(meas_path, "measurements")
    where = str(meas_path)
    preds, info = link_predictions(sweep_npz, meas, where)
    y = np.asarray(meas["path_gain_db"], np.float64)[:, 0]
    split = np.asarray(meas["split"])
    train, test = split == 0, split == 1
    if not train.any() or not test.any():
        raise ValueError(f"{where}: the split column leaves no training or no test link")
    itu = score(preds[0], y, train, test)
    best, maes = choose_candidate(preds, y, train)
    cal = score(preds[best], y, train, test)
    chosen = info["candidates"][best]
    out = {
        "method": "Sionna RT on a labelled mesh, ITU materials per label, plus one system gain fitted on the "
                  "training links (the unknown transmit power and antenna gains); calibrated: the wall material "
                  "and thickness of lowest training MAE from a grid",
        "sweep": str(sweep_npz), "measurements": str(meas_path), "mesh": info["mesh"], "freq_hz": info["freq_hz"],
        "metrics": {"mae_db": itu["mae_db"], "mae_train_db": itu["mae_train_db"], "rmse_db": itu["rmse_db"],
                    "calibrated_mae_db": cal["mae_db"], "calibrated_mae_train_db": cal["mae_train_db"],
                    "calibrated_rmse_db": cal["rmse_db"], "num_train": int(train.sum()), "num_test": int(test.sum()),
                    "links_without_path": int(np.sum(preds[0] <= NO_PATH_DB))},
        "itu": {"system_gain_db": itu["system_gain_db"], "materials": info["candidates"][0]["materials"]},
        "calibrated": {"chosen": chosen["name"], "wall_material": chosen["wall_material"],
                       "wall_thickness": chosen["wall_thickness"], "system_gain_db": cal["system_gain_db"],
                       "grid": [{"name": c["name"], "mae_train_db": float(m)}
                                for c, m in zip(info["candidates"], maes)]},
        "label_names": info["label_names"], "physics": info["physics"], "reciprocity_swap": info["reciprocity_swap"],
        "sweep_solve_s": float(sum(info["solve_s"])), "wall_time_s": time.time() - t0,
    }
    _write_json(results_path, out)
    return out


def _write_json(path, data: dict) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(data, indent=2) + "\n")
    tmp.replace(path)      # never a half-written results file


# --------------------------------------------------------------------------------------------
# one guessed material for the whole mesh
# --------------------------------------------------------------------------------------------
def one_material(mesh_path, meas_path, material: str, thickness_m: float, results_path) -> dict:
    """Sionna RT on the whole mesh as one ITU material, no gain fitted; scored on the file's test rows."""
    from rfir_core.artifacts import read_artifact
    from rfir_core.progress import NullProgress
    from rfir_stages.geom.mesh_io import read_ply_mesh
    from rfir_stages.simulate.radio_scene import load_radio_scene
    from rfir_stages.simulate.rssi import simulate_rssi
    from rfir_stages.simulate.scenes import SceneObject, SceneSpec
    from rfir_stages.simulate.settings import parse_settings

    t0 = time.time()
    meas = read_artifact(meas_path, "measurements")
    _, tx, ti = device_table(meas["tx_id"], meas["tx_pos"], "transmitter", str(meas_path))
    _, rx, ri = device_table(meas["rx_id"], meas["rx_pos"], "receiver", str(meas_path))
    freqs = np.asarray(meas["freq_hz"], np.float64)[:1]
    mesh = read_ply_mesh(mesh_path)
    obj = SceneObject("reconstructed", 0, np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int32),
                      material, "plaster", (0.8, 0.8, 0.8), thickness_m)
    spec = SceneSpec("reconstructed", "room", [obj], np.stack([mesh.vertices.min(0), mesh.vertices.max(0)]))
    settings = parse_settings(None)
    work = Path(results_path).with_suffix("")
    radio = load_radio_scene(spec, work.parent / (work.name + "_radio"), float(freqs[0]), settings.material_effects())
    t_solve = time.time()
    _, power, _, _, _, _ = simulate_rssi(radio, tx, rx, freqs, settings.physics_for("rssi"), NullProgress(),
                                         "ray tracing")
    solve_s = time.time() - t_solve
    pred = 10 * np.log10(np.maximum(power[:, 0], 1e-25))[ti * len(rx) + ri]    # rows Tx-major; no path: -250 dB
    y = np.asarray(meas["path_gain_db"], np.float64)[:, 0]
    test = np.asarray(meas["split"]) == 1
    out = {"method": f"Sionna RT on {mesh_path}, one guessed material ({material}, {thickness_m} m), simulate's "
                     "default physics", "mesh_triangles": int(len(mesh.faces)),
           "measurements": str(meas_path), "num_test": int(test.sum()),
           "mae_db": float(np.mean(np.abs(pred[test] - y[test]))),
           "mae_all_db": float(np.mean(np.abs(pred - y))), "links_without_path": int(np.sum(pred <= NO_PATH_DB)),
           "solve_s": solve_s, "wall_s": time.time() - t0}
    _write_json(results_path, out)
    return out


def _words(text: str) -> list[str]:
    return [w.strip() for w in text.split(",") if w.strip()]


def main(argv=None) -> int:
    from rfir_core.errors import RfirError

    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv[:1] == ["sweep"]:
            ap = argparse.ArgumentParser(prog="baseline_raytrace.py sweep", description=sweep.__doc__.split("\n")[0])
            ap.add_argument("mesh", help="labelled PLY with labels.json beside it")
            ap.add_argument("measurements")
            ap.add_argument("--out", required=True, help="the sweep's npz")
            ap.add_argument("--wall-materials", default=WALL_MATERIALS, help="ITU materials tried for the walls")
            ap.add_argument("--wall-thickness", default=WALL_THICKNESS,
                            help="wall thicknesses tried: 'plan' (each wall's own) or metres")
            a = ap.parse_args(argv[1:])
            out = sweep(a.mesh, a.measurements, a.out, _words(a.wall_materials), _words(a.wall_thickness),
                        say=lambda m: print(m, flush=True))
        elif argv[:1] == ["score"]:
            ap = argparse.ArgumentParser(prog="baseline_raytrace.py score", description=score_sweep.__doc__)
            ap.add_argument("sweep")
            ap.add_argument("measurements")
            ap.add_argument("--results", required=True)
            a = ap.parse_args(argv[1:])
            out = score_sweep(a.sweep, a.measurements, a.results)
        else:
            ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
            ap.add_argument("mesh")
            ap.add_argument("measurements")
            ap.add_argument("--material", default="concrete")
            ap.add_argument("--thickness", type=float, default=0.2, help="slab thickness Sionna assumes, m")
            ap.add_argument("--results", required=True)
            a = ap.parse_args(argv)
            out = one_material(a.mesh, a.measurements, a.material, a.thickness, a.results)
    except (ValueError, OSError, RfirError) as exc:
        print(f"baseline_raytrace: {exc}", file=sys.stderr)
        return 2
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
