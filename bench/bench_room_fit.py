"""Benchmark of `rfir rf-fit` on RSSI links (the room model, docs/physics.md section 8.10): how its cost grows with the
number of Gaussians and with the number of links it fits (issue 23's speed target: the classroom within
5 minutes on the 2-core CPU, model selection included).

    .venv/bin/python bench/bench_room_fit.py                      # the classroom's layout, synthetic levels
    .venv/bin/python bench/bench_room_fit.py --measurements M.h5  # the simulated classroom's links instead
    .venv/bin/python bench/bench_room_fit.py --quick              # two geometries, two link counts
    .venv/bin/python bench/bench_room_fit.py --survey M.h5 --scene S.h5 [--links 1000,2000,5000] [--repeat 3]
                                                                  # a survey's fit against its training links, with a
                                                                  # gain per anchor and a gain per position too
    .venv/bin/python bench/bench_room_fit.py --survey M.h5 --scene S.h5 --bounded 50000
                                                                  # and a 50,000-link survey: fit, then predict

The survey of the figures is the measured-like flat (docs/simulate.md), every row a training link (--all-rows):

    rfir simulate flat SIM --no-photos
    python scripts/measured_like.py SIM ML --seed 0
    rfir mesh-gaussians ML/floorplan/flat_floorplan.ply -o ML/plan_scene.h5 --spacing 0.8
    .venv/bin/python bench/bench_room_fit.py --survey ML/measurements_random.h5 --scene ML/plan_scene.h5 --all-rows

Needs no simulator: the classroom's meshes are built by code and tiled as `rfir mesh-gaussians
classroom_gt.ply --spacing S [--object-cells N --rectangles --drop-contact-faces]` tiles them, at five tilings
from 2.6k to 105k surfels
(uniform spacings 0.8, 0.25 and 0.15 m, whose planar patches stay the same surfaces; and furniture at
size / 12 and size / 24, which add patches). The links are the classroom's layout (`rfir simulate
classroom`: 24 transmitters x 440 receivers, 20 % test), their levels free space plus N(0, 3 dB) unless
`--measurements` gives the simulated ones (the fit's cost depends on the geometry and the number of
links, not on the levels). Each fit is `rfir --seed 0 --set rf_fit.room.fit_links=L rf-fit SCENE MEAS -o
rf.h5` in a process of its own, as a user runs it (python start-up included). Printed per fit: Gaussians,
planar patches, specular paths per link, links fitted, wall and CPU seconds (user + sys: the machine may
be shared, printed with the load average), the fit's own split (trace: patches, paths, visibility;
fit: the optimiser with its starting materials) and the peak resident memory. Then the growth exponents
(log-log slope of the CPU time between the runs) and bench/room_fit.json.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from bench_rssi import FREQ, classroom_fields
from rfir_core.artifacts import read_artifact, write_artifact
from rfir_core.physics.closed_forms import friis_path_gain
from rfir_stages.geom import write_scene_artifact
from rfir_stages.simulate import build_scene
from rfir_stages.simulate.rssi import grid_positions
from rfir_stages.simulate.settings import parse_settings

TARGET_S = 300.0                      # issue 23: rf-fit of the classroom within 5 minutes
# (spacing m, object cells): uniform tilings keep the patches and grow the Gaussians; object cells add
# furniture patches as well.
TILINGS = {"full": [(0.8, 0), (0.25, 0), (0.15, 0), (0.8, 12), (0.4, 24)], "quick": [(0.8, 0), (0.8, 12)]}
LINKS = {"full": [500, 1500, 4000], "quick": [500, 1500]}
LINKS_TILING = (0.8, 12)              # the link counts are run on this tiling (the default of mesh-gaussians --preset room)


def classroom_links(seed: int = 0) -> dict:
    """The layout of `rfir simulate classroom` (its [simulate.rssi] settings: 6 x 4 transmitters at 2.2 m,
    22 x 20 receivers at 1.0 m) with free-space levels plus N(0, 3 dB): the fields of a measurements artifact."""
    s, bounds = parse_settings(None, scene="classroom"), build_scene("classroom").bounds
    tx = grid_positions(bounds, *s.tx_grid, s.tx_height_m, s.tx_margin_m)
    rx = grid_positions(bounds, *s.rx_grid, s.rx_height_m, s.rx_margin_m)
    t, r = np.repeat(tx, len(rx), 0), np.tile(rx, (len(tx), 1))
    rng = np.random.default_rng(seed)
    gain = 10 * np.log10(friis_path_gain(np.linalg.norm(r - t, axis=1), FREQ)) + rng.normal(0, 3.0, len(t))
    split = (rng.random(len(t)) < 0.2).astype(np.int64)
    return {"tx_pos": t, "rx_pos": r, "freq_hz": np.array([FREQ]), "path_gain_db": gain[:, None],
            "split": split, "tx_id": np.repeat(np.arange(len(tx)), len(rx)), "scene_bounds": bounds}


def run_fit(scene: Path, meas: Path, out: Path, fit_links: int) -> dict:
    """One `rfir rf-fit` in its own process (run_cli): wall, CPU and peak memory of that process, and what it logged."""
    run = run_cli(["--seed", "0", "--set", f"rf_fit.room.fit_links={fit_links}", "rf-fit", str(scene), str(meas),
                   "-o", str(out)])
    text = run.pop("log")
    attrs = read_artifact(out, "rf").free["training@attrs"]
    patches = re.search(r"Gaussians in (\d+) planar patches", text)
    paths = re.search(r"\(([\d.]+) per link\)", text)
    return {"fit_links": fit_links, **run, "trace_s": float(attrs["trace_time_s"]),
            "fit_s": float(attrs["fit_time_s"]), "stage_s": float(attrs["wall_time_s"]),
            "patches": int(patches.group(1)) if patches else None,
            "paths_per_link": float(paths.group(1)) if paths else None,
            "train_mae_db": float(attrs["train_mae_db"])}


def run_cli(args: list[str]) -> dict:
    """One `rfir ARGS` in its own process: wall and CPU seconds (user + sys) and peak resident memory."""
    t0 = time.time()
    with tempfile.TemporaryFile("w+") as log:
        proc = subprocess.Popen([str(Path(sys.executable).with_name("rfir")), *args], stdout=log,
                                stderr=subprocess.STDOUT, text=True)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.time() - t0
        log.seek(0)
        text = log.read()
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit(f"bench_room_fit: rfir {' '.join(args[:3])} ... failed:\n{text[-3000:]}")
    return {"wall_s": wall, "cpu_s": usage.ru_utime + usage.ru_stime, "peak_rss_mb": usage.ru_maxrss / 1024,
            "load_average_1min": os.getloadavg()[0], "log": text}


# the links the materials were fitted on, as rf-fit prints them (evenly spaced links, or whole devices)
FITTED = re.compile(r"(?:fitting|fitted) on (?:all )?(\d+)")


def survey_fit(scene: Path, meas: Path, out: Path, links: int, device_gains: str = "auto") -> dict:
    """`rfir --seed 0 --set rf_fit.max_links=LINKS --set rf_fit.room.device_gains=GAINS rf-fit SCENE MEAS` (every
    setting else at its default: the band chosen by validation on measured data, the device gains too where GAINS
    is auto): the training links evenly thinned to `links`."""
    row = run_cli(["--seed", "0", "--set", f"rf_fit.max_links={links}", "--set",
                   f"rf_fit.room.device_gains={device_gains}", "rf-fit", str(scene), str(meas), "-o", str(out)])
    attrs = read_artifact(out, "rf").free["training@attrs"]
    fitted = FITTED.search(row.pop("log"))
    return {**row, "links": links, "device_gains": device_gains,
            "links_fitted": int(fitted.group(1)) if fitted else links,
            "trace_s": float(attrs["trace_time_s"]), "fit_s": float(attrs["fit_time_s"]),
            "train_mae_db": float(attrs["train_mae_db"])}


def gain_settings(meas: Path) -> dict:
    """{label: rf_fit.room.device_gains} of the survey in `meas`: a gain per anchor (the side with fewer distinct
    positions) and a gain per surveyed position beside them ("both": what a walk survey whose roaming side the
    validation gives gains is fitted with)."""
    m = read_artifact(meas, "measurements")
    count = {s: len(np.unique(np.asarray(m[f"{s}_pos"]), axis=0)) for s in ("tx", "rx")}
    anchor = min(count, key=count.get)
    return {f"a gain per anchor ({anchor}, {count[anchor]})": anchor,
            f"and per position ({max(count, key=count.get)}, {max(count.values())})": "both"}


def synthetic_survey(meas: Path, out: Path, num_links: int, seed: int = 0) -> None:
    """A survey of num_links links over the extent of `meas`: the same fixed receivers (its rx positions and ids), a
    tag at uniform positions at the survey's tag heights, free-space levels plus N(0, 3 dB) and a 3 dB gain per
    receiver; no simulator recorded (measured data: rf-fit chooses device gains and band by validation)."""
    m = read_artifact(meas, "measurements")
    tx, rx = np.asarray(m["tx_pos"], np.float64), np.asarray(m["rx_pos"], np.float64)
    anchors, rx_id = np.unique(rx, axis=0, return_inverse=True)
    rng = np.random.default_rng(seed)
    positions = num_links // len(anchors) + 1
    tag = rng.uniform(tx.min(0), tx.max(0), (positions, 3))
    t, a = np.repeat(tag, len(anchors), 0)[:num_links], np.tile(np.arange(len(anchors)), positions)[:num_links]
    r = anchors[a]
    gain = rng.normal(0.0, 3.0, len(anchors))
    level = 10 * np.log10(friis_path_gain(np.linalg.norm(r - t, axis=1), float(np.asarray(m["freq_hz"])[0])))
    data = {"tx_pos": t, "rx_pos": r, "freq_hz": np.asarray(m["freq_hz"], np.float64)[:1],
            "path_gain_db": (level + gain[a] + rng.normal(0.0, 3.0, len(t)))[:, None],
            "split": (rng.random(len(t)) < 0.2).astype(np.int64), "tx_id": np.repeat(np.arange(positions),
                                                                                       len(anchors))[:num_links],
            "rx_id": a.astype(np.int64)}
    write_artifact(out, "measurements", data, attrs={"task": "rssi", "scene": str(m.attrs.get("scene", ""))})


def all_rows(meas: Path, out: Path) -> Path:
    """A copy of the measurements `meas` at `out` whose every row is a training link (split 0), the simulator's
    record kept (rf-fit reads the interactions per path and the measured-like transform from it)."""
    m = read_artifact(meas, "measurements")
    free = {"simulator": {**m.free.get("simulator", {}), "@attrs": m.free.get("simulator@attrs", {})}} \
        if "simulator@attrs" in m.free else None
    write_artifact(out, "measurements", {**m.data, "split": np.zeros(len(m["tx_pos"]), np.int64)}, attrs=m.attrs,
                   free=free)
    return out


def survey_main(args) -> None:
    """--survey: rf-fit's time and peak memory against the training links of a survey (medians of --repeat runs)
    with a gain per anchor and with a gain per position beside it (gain_settings), the growth exponent of each,
    and with --bounded N a synthetic N-link survey fitted and predicted (chunked)."""
    links = [int(x) for x in args.links.split(",")]
    source = args.survey
    fmt = "{:<34} {:>7} {:>7} {:>8} {:>8} {:>8} {:>8} {:>8} {:>5}"
    print(fmt.format("device gains", "links", "fitted", "wall s", "CPU s", "trace s", "fit s", "peak MB", "load"),
          flush=True)
    rows, growth = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        if args.all_rows:
            args.survey = all_rows(args.survey, d / "all_rows.h5")
        for label, gains in gain_settings(args.survey).items():
            these = []
            for n in links:
                runs = [survey_fit(args.scene, args.survey, d / "rf.h5", n, gains) for _ in range(args.repeat)]
                row = {k: float(np.median([r[k] for r in runs])) for k in runs[0] if k != "device_gains"}
                row.update(device_gains=gains, runs=runs)
                these.append(row)
                print(fmt.format(label, n, int(row["links_fitted"]), f"{row['wall_s']:.1f}", f"{row['cpu_s']:.1f}",
                                 f"{row['trace_s']:.1f}", f"{row['fit_s']:.1f}", f"{row['peak_rss_mb']:.0f}",
                                 f"{row['load_average_1min']:.1f}"), flush=True)
            rows += these
            if len(these) > 1:
                growth[gains] = slope(these, "links")
                print(f"growth ({label}): CPU seconds ~ links^{growth[gains]:.2f} (log-log slope, "
                      f"{links[0]}..{links[-1]} links)", flush=True)
        bounded = None
        if args.bounded:
            meas = d / "bounded.h5"
            synthetic_survey(args.survey, meas, args.bounded)
            fit = run_cli(["--seed", "0", "rf-fit", str(args.scene), str(meas), "-o", str(d / "rf_b.h5")])
            fitted = FITTED.search(fit.pop("log"))
            pred = run_cli(["predict", "rssi", str(d / "rf_b.h5"), "--measurements", str(meas), "-o",
                            str(d / "p_b.h5")])
            pred.pop("log")
            bounded = {"links": args.bounded, "links_fitted": int(fitted.group(1)) if fitted else None,
                       "fit": fit, "predict": pred}
            for what, r in (("rf-fit", fit), ("predict rssi (every link, in blocks)", pred)):
                print(f"{args.bounded} links, {what}: {r['wall_s']:.1f} s wall, {r['cpu_s']:.1f} s CPU, "
                      f"peak {r['peak_rss_mb']:.0f} MB (load {r['load_average_1min']:.1f})", flush=True)
    out = {"survey": str(source), "all_rows": bool(args.all_rows), "scene": str(args.scene), "repeat": args.repeat,
           "rows": rows,
           "cpu_vs_links": growth, "bounded": bounded,
           "note": "medians of `repeat` runs per device-gain setting (rf_fit.room.device_gains); cpu_s: user + sys of "
                   "the rf-fit process; links_fitted: the links the materials were fitted on (rf_fit.room.fit_links: "
                   "evenly spaced, or whole devices where a gain per position would keep too few); cpu_vs_links: "
                   "log-log slope of CPU seconds against links per setting"}
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {args.out}")


def slope(rows: list[dict], x: str, y: str = "cpu_s") -> float:
    """Least-squares slope of log y against log x: cost ~ x ** slope over the rows."""
    return float(np.polyfit(np.log([r[x] for r in rows]), np.log([r[y] for r in rows]), 1)[0])


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--measurements", type=Path, help="a classroom measurements artifact (else synthetic levels)")
    ap.add_argument("--quick", action="store_true", help="two tilings and two link counts")
    ap.add_argument("--out", type=Path, default=None, help="JSON written (default: room_fit.json, room_survey.json)")
    ap.add_argument("--survey", type=Path, help="a survey's measurements: rf-fit against its training links")
    ap.add_argument("--scene", type=Path, help="the survey's scene (with --survey)")
    ap.add_argument("--links", default="1000,2000,5000", help="training links to fit (with --survey)")
    ap.add_argument("--repeat", type=int, default=1, help="runs per link count, medians printed (with --survey)")
    ap.add_argument("--all-rows", action="store_true", help="every row of the survey a training link (its split "
                                                             "column set to train in a copy; with --survey)")
    ap.add_argument("--bounded", type=int, default=0, help="also a synthetic survey of this many links over the "
                                                           "survey's extent, fitted and predicted (with --survey)")
    args = ap.parse_args()
    if args.survey is not None:
        if args.scene is None:
            ap.error("--survey needs --scene")
        args.out = args.out or Path(__file__).with_name("room_survey.json")
        survey_main(args)
        return
    args.out = args.out or Path(__file__).with_name("room_fit.json")
    size = "quick" if args.quick else "full"
    fmt = "{:>8} {:>6} {:>7} {:>6} {:>6} {:>8} {:>7} {:>7} {:>7} {:>8} {:>5}"
    print(fmt.format("Gaussians", "tiling", "patches", "paths", "links", "wall s", "CPU s", "trace s", "fit s",
                     "peak MB", "load"), flush=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        d = Path(tmp)
        meas = args.measurements
        if meas is None:
            meas = d / "meas.h5"
            # synthetic levels from ideal devices: no device gains fitted (rf_fit.room.device_gains = "auto")
            write_artifact(meas, "measurements", classroom_links(), attrs={"task": "rssi", "scene": "classroom"},
                           free={"simulator": {"@attrs": {"simulator": "bench_room_fit synthetic levels"}}})
        runs = [(t, 1500) for t in TILINGS[size]] + [(LINKS_TILING, n) for n in LINKS[size] if n != 1500]
        for (spacing, cells), fit_links in runs:
            scene = d / f"scene_{spacing:g}_{cells}.h5"
            if not scene.exists():
                fields, names = classroom_fields(spacing, cells)
                write_scene_artifact(scene, fields, label_names=names)
            row = {"gaussians": int(read_artifact(scene, "scene")["gaussians/means"].shape[0]),
                   "spacing_m": spacing, "object_cells": cells, **run_fit(scene, meas, d / "rf.h5", fit_links)}
            rows.append(row)
            print(fmt.format(row["gaussians"], f"{spacing:g}/{cells}", row["patches"], f"{row['paths_per_link']:.1f}",
                             fit_links, f"{row['wall_s']:.1f}", f"{row['cpu_s']:.1f}", f"{row['trace_s']:.1f}",
                             f"{row['fit_s']:.1f}", f"{row['peak_rss_mb']:.0f}", f"{row['load_average_1min']:.1f}"),
                  flush=True)
    uniform = [r for r in rows if r["object_cells"] == 0 and r["fit_links"] == 1500]
    by_links = [r for r in rows if (r["spacing_m"], r["object_cells"]) == LINKS_TILING]
    growth = {"cpu_vs_gaussians_uniform": slope(uniform, "gaussians") if len(uniform) > 1 else None,
              "cpu_vs_fit_links": slope(by_links, "fit_links") if len(by_links) > 1 else None,
              "trace_vs_fit_links": slope(by_links, "fit_links", "trace_s") if len(by_links) > 1 else None,
              "fit_vs_fit_links": slope(by_links, "fit_links", "fit_s") if len(by_links) > 1 else None}
    print("growth (log-log slope of CPU seconds): " + ", ".join(
        f"{k} {v:.2f}" for k, v in growth.items() if v is not None))
    worst = max(r["wall_s"] for r in rows)
    print(f"longest fit {worst:.0f} s wall against the {TARGET_S:.0f} s target")
    out = {"rows": rows, "growth": growth, "target_s": TARGET_S, "measurements": str(args.measurements or "synthetic"),
           "note": "cpu_s: user + sys of the rf-fit process; trace_s / fit_s: the fit's own split (artifact); "
                   "growth: least-squares slope of log CPU seconds against log Gaussians (uniform tilings, "
                   "1500 links) and against log links fitted (the size / 12 tiling)"}
    args.out.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
