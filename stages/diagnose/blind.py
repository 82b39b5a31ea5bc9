"""A blind test of `rfir diagnose`: cases with hidden effects injected into copies of simulated data,
diagnosed without their answers, then scored (command line: scripts/diagnose_blind.py).

Two small scenes are simulated once with `rfir simulate` (the classroom's RSSI links, 6 Tx x 110 Rx with
receivers also outside the walls; the lego on a physical-optics turntable, 360 aspects) and cached in
DATA/scenes. Each case is a folder DATA/cases/case_NN with the clean simulation as the model and a copy of
its measurements with the hidden effect(s) and 0.5 dB of Gaussian noise. The answers are written apart,
to DATA/answers.json; case numbers are shuffled so a name says nothing. `run_set` diagnoses every case reading
only its two files (and the room's geometry for the crossings), and opens the answers only to score:
a case is right when the named effects are the hidden ones (for an effect outside the catalogue: nothing
named and the headline says "structure the model lacks" by the right axis; for the negative: nothing
named), and every named step shrinks the held-out gap. OUT/diagnose_blind.{json,md} hold the table.
"""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

NOISE_DB = 0.5
ROOM_SETS = ["--set", "simulate.rssi.tx_grid=[3,2]", "--set", "simulate.rssi.rx_grid=[11,10]",
             "--set", "simulate.rssi.rx_margin_m=-1.0"]
LEGO_SETS = ["--set", "simulate.rcs.freqs_hz=[2.4e9]", "--set", "simulate.rcs.ranges_m=[3.0]",
             "--set", "simulate.rcs_backend=po"]
OBSTACLE_BOX = (5.5, 2.5, 7.0, 4.5)        # x0, y0, x1, y1 [m] inside the classroom, clear of every Tx
TX_OFFSETS_DB = (0.0, -4.0, 2.5, -1.5, 3.5, -6.0)

# (key, scene, hidden effects (catalogue names; [] for none), axis for an effect outside the catalogue, what)
CASES = [
    ("gain", "room", ["gain_offset"], None, "-4 dB on every link"),
    ("glass", "room", ["crossing_loss"], None, "-5 dB per object crossed (a glass partition)"),
    ("tx_cal", "room", ["tx_offsets"], None, "a different offset per transmitter"),
    ("obstacle", "room", ["obstacle"], None, "-8 dB on links crossing a box"),
    ("floor", "room", ["noise_floor"], None, "noise floor at -80 dB"),
    ("clip", "room", ["dynamic_range"], None, "weak links read the floor (20 % quantile)"),
    ("gain_floor", "room", ["gain_offset", "noise_floor"], None, "-3 dB gain and a -78 dB noise floor"),
    ("tx_glass", "room", ["tx_offsets", "crossing_loss"], None, "Tx offsets and -4 dB per crossing"),
    ("saturation", "room", ["saturation"], None, "links above the 75 % quantile clipped"),
    ("rx_cal", "room", ["rx_offsets"], None, "a random offset per receiver (3 dB rms)"),
    ("negative", "room", [], None, "noise only"),
    ("distance_bump", "room", [], "range", "-6 dB between 4 and 7 m (outside the catalogue)"),
    ("rcs_gain", "lego", ["gain_offset"], None, "+3 dB"),
    ("rcs_turntable", "lego", ["turntable_offset"], None, "aspect recorded 3 deg off"),
    ("rcs_leakage", "lego", ["leakage"], None, "coherent coupling at -80 dB, phase 60 deg"),
    ("rcs_diffuse", "lego", ["diffuse_lobe"], None, "incoherent diffuse power, no phases in the file"),
    ("rcs_sector", "lego", [], "aspect", "+5 dB over aspects 60-120 deg (outside the catalogue)"),
    ("rcs_turn_gain", "lego", ["turntable_offset", "gain_offset"], None, "3 deg aspect offset and -2 dB"),
]
QUICK = ("gain", "tx_cal", "negative", "rcs_sector")


def _rfir() -> str:
    return str(Path(sys.executable).with_name("rfir"))


def _simulate(scenes: Path) -> None:
    """The two clean simulations and the room's geometry, once (cached in scenes/)."""
    scenes.mkdir(parents=True, exist_ok=True)
    jobs = [("room", ROOM_SETS + ["simulate", "classroom"], "rssi"), ("lego", LEGO_SETS + ["simulate", "lego"], "rcs")]
    for name, args, task in jobs:
        if not (scenes / name / "measurements.h5").exists():
            subprocess.run([_rfir(), *args, str(scenes / name), "--no-photos", "--task", task], check=True,
                           stdout=subprocess.DEVNULL)
    if not (scenes / "room_geometry.h5").exists():
        subprocess.run([_rfir(), "mesh-gaussians", str(scenes / "room" / "meshes" / "classroom_gt.ply"), "-o",
                        str(scenes / "room_geometry.h5"), "--spacing", "0.8"], check=True, stdout=subprocess.DEVNULL)


def _inject(key: str, meas, rng: np.random.Generator, geometry_path: Path) -> dict:
    """The measurement datasets of case `key`: the clean ones with the hidden effect(s) and noise."""
    from rfir_stages.diagnose.crossings import crossings_from_artifact
    from rfir_stages.diagnose.effects import BY_NAME
    from rfir_stages.diagnose.obstacle import segments_cross_boxes
    from rfir_stages.diagnose.rows import Rows

    from rfir_core.artifacts import read_artifact

    data = {k: np.asarray(v) for k, v in meas.data.items()}
    pg = data["path_gain_db"].astype(np.float64)
    tx, rx = data["tx_pos"], data["rx_pos"]
    lin = lambda db: 10 ** (db / 10)   # noqa: E731
    channel = data.get("channel")
    post = None      # a clip applied after the noise (the receiver reports it)
    if key in ("glass", "tx_glass"):
        n = crossings_from_artifact(read_artifact(geometry_path, ("scene", "rf")), tx, rx)
        pg = pg + (-5.0 if key == "glass" else -4.0) * n[:, None]
    if key in ("tx_cal", "tx_glass"):
        ids = np.unique(np.round(tx, 3), axis=0, return_inverse=True)[1].reshape(-1)
        pg = pg + np.asarray(TX_OFFSETS_DB)[ids][:, None]
    if key == "gain":
        pg = pg - 4.0
    if key == "obstacle":
        pg = pg - 8.0 * segments_cross_boxes(tx[:, :2], rx[:, :2], np.asarray([OBSTACLE_BOX]))[:, :1]
    if key == "floor":
        pg = 10 * np.log10(lin(pg) + lin(-80.0))
    if key == "gain_floor":
        pg = 10 * np.log10(lin(pg - 3.0) + lin(-78.0))
    if key == "clip":
        post = ("floor", float(np.quantile(pg, 0.2)))
    if key == "saturation":
        post = ("ceiling", float(np.quantile(pg, 0.75)))
    if key == "rx_cal":
        ids = np.unique(np.round(rx, 3), axis=0, return_inverse=True)[1].reshape(-1)
        pg = pg + rng.normal(0.0, 3.0, ids.max() + 1)[ids][:, None]
    if key == "distance_bump":
        d = np.linalg.norm(rx - tx, axis=1)
        pg = pg - 6.0 * ((d > 4.0) & (d < 7.0))[:, None]
    if key in ("rcs_gain",):
        pg = pg + 3.0
    if key in ("rcs_turntable", "rcs_turn_gain"):
        rows = Rows(pg[:, 0], pg[:, 0].copy(), np.ones(len(pg), bool), np.ones(len(pg), bool), tx, rx,
                    np.full(len(pg), float(data["freq_hz"][0])), "rcs", data["aspect_rad"], data["range_m"])
        pg = pg + BY_NAME["turntable_offset"].correction(np.array([3.0]), rows, pg[:, 0])[:, None]
        if key == "rcs_turn_gain":
            pg = pg - 2.0
    if key == "rcs_leakage":
        channel = channel + 10 ** (-80.0 / 20) * np.exp(1j * np.radians(60.0))
        pg = 10 * np.log10(np.abs(channel) ** 2)
    if key == "rcs_diffuse":
        rows = Rows(pg[:, 0], pg[:, 0].copy(), np.ones(len(pg), bool), np.ones(len(pg), bool), tx, rx,
                    np.full(len(pg), float(data["freq_hz"][0])), "rcs", data["aspect_rad"], data["range_m"])
        ref = rows.reference_power()
        level = 10 * np.log10(np.median(lin(pg[:, 0])) / np.median(ref))   # as strong as the median echo
        pg = pg + BY_NAME["diffuse_lobe"].correction(np.array([level]), rows, pg[:, 0])[:, None]
        channel = None    # the file has no phases
    if key == "rcs_sector":
        asp = np.degrees(np.mod(data["aspect_rad"], 2 * np.pi))
        pg = pg + 5.0 * ((asp >= 60) & (asp <= 120))[:, None]
    noisy = pg + rng.normal(0.0, NOISE_DB, pg.shape)
    if post is not None:
        noisy = np.maximum(noisy, post[1]) if post[0] == "floor" else np.minimum(noisy, post[1])
    if channel is not None:   # keep |channel|^2 = path gain, the phase as it was
        data["channel"] = np.exp(1j * np.angle(channel)) * 10 ** (noisy / 20)
    else:
        data.pop("channel", None)
    if "rcs_dbsm" in data:
        data["rcs_dbsm"] = data["rcs_dbsm"] + (noisy - data["path_gain_db"])
    data["path_gain_db"] = noisy
    return data


def make(data_dir: Path, quick: bool = False, seed: int = 0) -> dict:
    """Write DATA/cases/case_NN/{model,measurements}.h5 and DATA/answers.json; returns the answers."""
    from rfir_core.artifacts import read_artifact, write_artifact

    data_dir = Path(data_dir)
    scenes = data_dir / "scenes"
    _simulate(scenes)
    cases = [c for c in CASES if not quick or c[0] in QUICK]
    order = np.random.default_rng(seed).permutation(len(cases))
    shutil.rmtree(data_dir / "cases", ignore_errors=True)
    answers = {}
    for number, i in enumerate(order, 1):
        key, scene, effects, axis, what = cases[i]
        case = f"case_{number:02d}"
        folder = data_dir / "cases" / case
        folder.mkdir(parents=True, exist_ok=True)
        clean = read_artifact(scenes / scene / "measurements.h5", "measurements")
        attrs = {"task": str(clean.attrs["task"]), "scene": "blind"}
        sim = clean.free.get("simulator@attrs", {})
        if sim.get("antenna_tx") == "horn":   # the cases carry no simulator group: state the radar's horn
            attrs["antenna_tx"] = attrs["antenna_rx"] = f"horn:{float(sim['horn_hpbw_deg']):g}"
        write_artifact(folder / "model.h5", "measurements", {k: np.asarray(v) for k, v in clean.data.items()},
                       attrs=attrs)
        rng = np.random.default_rng(seed * 1000 + 17 * (i + 1))
        write_artifact(folder / "measurements.h5", "measurements",
                       _inject(key, clean, rng, scenes / "room_geometry.h5"), attrs=attrs)
        answers[case] = {"key": key, "scene": scene, "effects": effects, "axis": axis, "what": what}
    (data_dir / "answers.json").write_text(json.dumps(answers, indent=2) + "\n")
    return answers


def diagnose_cases(data_dir: Path, out_dir: Path) -> dict:
    """Diagnose every case from its two files (answers unread): case -> what diagnose said."""
    from rfir_stages.diagnose import run

    said = {}
    for folder in sorted((Path(data_dir) / "cases").iterdir()):
        t0 = time.time()
        geometry = data_dir / "scenes" / "room_geometry.h5"
        from rfir_core.artifacts import read_artifact

        rssi = str(read_artifact(folder / "measurements.h5", "measurements").attrs.get("task")) == "rssi"
        res = run(folder / "model.h5", folder / "measurements.h5", Path(out_dir) / "cases" / folder.name,
                  geometry_path=geometry if rssi else None)
        results = json.loads((res.out_dir / "results.json").read_text())
        said[folder.name] = {"named": [n["effect"] for n in res.named], "headline": res.headline,
                             "lacking": [w["axis"] for w in results["lacking"] if w["large"]],
                             "steps": [(s.get("named"), s["test_mae_before_db"], s.get("test_mae_after_db"))
                                       for s in res.steps if s.get("named")],
                             "mae_before_db": res.mae_before_db, "mae_after_db": res.mae_after_db,
                             "seconds": time.time() - t0}
    return said


def score(said: dict, answers: dict) -> list[dict]:
    """One row per case: truth, what was said, right or not (module docstring)."""
    rows = []
    for case, truth in sorted(answers.items()):
        s = said[case]
        shrinks = all(after < before for _n, before, after in s["steps"])
        if truth["axis"]:
            right = not s["named"] and s["headline"].startswith("structure the model lacks") and \
                any(truth["axis"] in a for a in s["lacking"])
        else:
            right = sorted(s["named"]) == sorted(truth["effects"])
        rows.append({"case": case, **truth, "named": s["named"], "headline": s["headline"], "right": bool(right),
                     "gap_shrinks": shrinks, "mae_before_db": s["mae_before_db"], "mae_after_db": s["mae_after_db"],
                     "seconds": s["seconds"]})
    return rows


def write_table(rows: list[dict], out_dir: Path) -> None:
    out_dir = Path(out_dir)
    negatives = [r for r in rows if not r["effects"] and not r["axis"]]
    summary = {"cases": len(rows), "right": sum(r["right"] for r in rows),
               "false_positives_on_negatives": sum(bool(r["named"]) for r in negatives),
               "gap_shrinks_for_every_named": all(r["gap_shrinks"] for r in rows),
               "max_seconds": max(r["seconds"] for r in rows), "total_seconds": sum(r["seconds"] for r in rows)}
    (out_dir / "diagnose_blind.json").write_text(json.dumps({"summary": summary, "cases": rows}, indent=2) + "\n")
    lines = ["# diagnose: blind set", "",
             f"{summary['right']} of {summary['cases']} right; false positives on the negative: "
             f"{summary['false_positives_on_negatives']}; every named step shrinks the held-out gap: "
             f"{'yes' if summary['gap_shrinks_for_every_named'] else 'no'}; "
             f"{summary['total_seconds']:.0f} s in all, at most {summary['max_seconds']:.1f} s per case.", "",
             "| case | scene | hidden | truth | named | headline | held-out MAE before -> after | right | s |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        truth = " + ".join(r["effects"]) or (f"outside the catalogue (by {r['axis']})" if r["axis"] else "nothing")
        lines.append(f"| {r['case']} | {r['scene']} | {r['what']} | {truth} | {' + '.join(r['named']) or '-'} | "
                     f"{r['headline']} | {r['mae_before_db']:.2f} -> {r['mae_after_db']:.2f} dB | "
                     f"{'yes' if r['right'] else '**no**'} | {r['seconds']:.1f} |")
    (out_dir / "diagnose_blind.md").write_text("\n".join(lines) + "\n")


def run_set(data_dir: Path, out_dir: Path, quick: bool = False) -> list[dict]:
    """Make the cases if DATA has none, diagnose every case blind, score, write OUT/diagnose_blind.{json,md}.

    quick: only the QUICK cases. Returns the score's rows (one per case)."""
    data_dir, out_dir = Path(data_dir), Path(out_dir)
    if not (data_dir / "answers.json").exists():
        make(data_dir, quick)
    out_dir.mkdir(parents=True, exist_ok=True)
    said = diagnose_cases(data_dir, out_dir)
    rows = score(said, json.loads((data_dir / "answers.json").read_text()))
    write_table(rows, out_dir)
    return rows
