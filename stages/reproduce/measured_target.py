"""The measured reproduce target: two public measured surveys and the measured-like flat, in one table.

The surveys: a BLE survey of the TETAM lab (tests/data/public_survey) and a Wi-Fi RTT survey of a lab hall
(tests/data/rtt_lab), each thinned, imported once per protocol (random positions, a held-out area, unseen
receivers) and fitted on its floor plan's surfels; the measured-like flat (docs/simulate.md) is a simulated BLE
survey with what the real ones have, scored the same way. Here: their constants (data folders, citations,
protocols, the table's methods), the steps each declares on a Plan, the table's rows and their labels and notes
(read from the step results when the table is written). targets.py registers target_measured in TARGETS.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from . import methods as M
from .plan import Plan, read_json
from .tables import Table

# The measured target: a public BLE survey (tests/data/public_survey/README.md): 12 fixed receivers (rx_id), one
# beacon (tx, tx_id) at 125 positions, mean RSSI per link, and the lab's floor plan.
SURVEY = Path("tests/data/public_survey")
SURVEY_CITE = ("*Position Annotated BLE RSSI Dataset for Indoor Localization* (F. S. Daniş, A. T. Naskali, "
               "A. T. Cemgil, C. Ersoy; IEEE Access 9:37022-37038, 2021), CC0 1.0; source, citations and the "
               "derived files: [tests/data/public_survey/README.md](../../tests/data/public_survey/README.md)")
# (name, `rfir import csv --split` protocol or None for the file's own split column, row text)
MEASURED_PROTOCOLS = (("random", None, "random 20 % of beacon positions"),
                      ("area", "block-tx:6", "held-out area"),
                      ("anchors", "holdout-rx:2", "unseen anchors"))
MEASURED_METHODS = ["rfir", "log-distance", "multi-wall", "nearest links", "ray tracing (ITU materials)",
                    "ray tracing (calibrated)"]
# quick variant's ray-tracing grid (wall materials, wall thicknesses); the full one is the script's default
MEASURED_QUICK_GRID = ("concrete,brick,metal", "plan")
# no radio-map cache in the fitted models (the table draws no maps; it takes rf-fit about 40 s)
MEASURED_FIT = {"rf_fit.room.map_visibility": "false"}


def _survey_data(r: Plan, key: str, links_csv: Path, walls_csv: Path, every: int,
                 protocols: tuple) -> tuple[dict[str, Path], Path]:
    """A measured survey's links (every `every`-th transmitter position) imported once per protocol under
    r.data/<key>/, and surfels of its floor plan (walls 3 m high, concrete floor and ceiling; `--preset
    room`): ({protocol name: survey.h5}, scene.h5)."""
    folder = r.data / key
    links, bare = folder / "links.csv", folder / "links_nosplit.csv"
    thin = [r.python, str(M.SCRIPTS / "survey_thin.py"), str(links_csv)]
    r.step(f"data__{key}_links", [*thin, str(links), "--every-tx", str(every)], links)
    r.step(f"data__{key}_links_nosplit", [*thin, str(bare), "--every-tx", str(every), "--drop-split"], bare)
    surveys = {}
    for name, protocol, _ in protocols:
        meas = folder / f"survey_{name}.h5"
        split = ["--split", protocol] if protocol else []
        r.step(f"data__{key}_survey_{name}", [r.rfir, "--seed", "0", "import", "csv", str(bare if protocol else links),
                                              "-o", str(meas), "--column", "sample_count=n_packets",
                                              "--column", "sample_std_db=rssi_std_db", *split], meas)
        surveys[name] = meas
    room = folder / "room.ply"
    r.step(f"data__{key}_room", [r.rfir, "import", "floorplan", str(walls_csv), "--height", "3.0",
                                 "-o", str(room), "--floor-material", "concrete", "--ceiling-material", "concrete"],
           room, [folder / "labels.json"])
    scene = folder / "scene.h5"
    r.step(f"data__{key}_surfels", [r.rfir, "mesh-gaussians", str(room), "-o", str(scene), "--preset", "room"], scene)
    return surveys, scene


def _measured_data(r: Plan) -> tuple[dict[str, Path], Path]:
    """The TETAM survey (quick: every measured_every_tx-th beacon position) per protocol, and its surfels."""
    return _survey_data(r, "measured", SURVEY / "tetam_links.csv", SURVEY / "tetam_walls.csv",
                        int(r.sizes.get("measured_every_tx", 1)), MEASURED_PROTOCOLS)


def _measured_fit_sets(r: Plan) -> dict:
    """rf-fit settings of the measured target's fits: configs/reproduce.toml measured_iterations Adam steps
    (its starts a fifth, at least 10), no radio-map cache."""
    n = int(r.sizes.get("measured_iterations") or r.sizes["iterations"])
    return {"rf_fit.physical.iterations": n, "rf_fit.physical.start_iterations": max(10, n // 5), **MEASURED_FIT}


def _measured_label(meas: Path, name: str, text: str, site: str = "TETAM lab",
                    receivers: str = "receivers") -> Callable[[], str]:
    """A row label read from the imported survey: which positions or receivers are test."""
    def label() -> str:
        import numpy as np

        from rfir_core.artifacts import read_artifact

        a = read_artifact(meas, "measurements")
        test = np.asarray(a["split"]) == 1
        tx, rx = np.asarray(a["tx_id"]), np.asarray(a["rx_id"])
        if name == "anchors":
            held = ", ".join(str(v) for v in np.unique(rx[test]))
            return f"{site}, {text} (rx_id {held}: {np.unique(rx[test]).size} of {np.unique(rx).size} {receivers})"
        return f"{site}, {text} ({np.unique(tx[test]).size} of {np.unique(tx).size} positions)"
    return label


def _diagnose_note(r: Plan, report: Path) -> Callable[[], str]:
    """A note from `rfir diagnose`'s results on the random fit: its headline, held-out MAE before and after."""
    def note() -> str:
        d = read_json(report.parent / "results.json")
        named = [n["effect"] for n in d.get("named", [])]
        return (f"`rfir diagnose` of the random fit ([report]({report.relative_to(r.out)})): "
                + (f"named {', '.join(named)}, " if named else "")
                + f"held-out MAE {d['mae_before_db']:.2f} -> {d['mae_after_db']:.2f} dB; {d['headline']}")
    return note


def target_measured(r: Plan) -> Table:
    """Two real measured surveys (public data sets: a BLE lab, 12 anchors, 125 beacon positions; a Wi-Fi lab
    hall, 6 access points, 168 phone positions): rfir's room model on the floor plan against the simple
    baselines, where the survey reaches (random positions) and where it does not (a held-out area, unseen
    anchors)."""
    t = Table("RSSI: measured surveys (TETAM lab BLE 2.44 GHz; lab hall Wi-Fi 5.2 GHz)", MEASURED_METHODS)
    surveys, scene = _measured_data(r)
    # every protocol file holds the same links: one Sionna sweep, scored on each split (quick: a 3-set grid)
    sweep, sweep_step = M.raytrace_sweep(r, "measured", r.data / "measured" / "room.ply", surveys["random"],
                                         *(MEASURED_QUICK_GRID if r.quick else ()))
    sionna = {}
    for name, _, text in MEASURED_PROTOCOLS:
        ours = M.rfir_rssi(r, f"measured_{name}", scene, surveys[name], "random", _measured_fit_sets(r))
        sionna[name] = M.raytrace_gain(r, f"measured_{name}", sweep, sweep_step, surveys[name])
        t.add(_measured_label(surveys[name], name, text), {
            "rfir": ours.cell(),
            "log-distance": ours.metric("baseline_log_distance_mae_db"),
            "multi-wall": ours.metric("baseline_multiwall_mae_db"),
            "nearest links": ours.metric("baseline_nearest_links_mae_db"),
            "ray tracing (ITU materials)": sionna[name].cell("metrics.mae_db"),
            "ray tracing (calibrated)": sionna[name].cell("metrics.calibrated_mae_db")})
    out = r.out / "measured_diagnose"
    report = out / "report.md"
    r.step("measured_random__diagnose", [r.rfir, "--seed", "0", "diagnose", str(r.data / "fits" / "measured_random.h5"),
                                         str(surveys["random"]), "-o", str(out)], report, [out / "results.json"])
    every = int(r.sizes.get("measured_every_tx", 1))
    t.notes += [f"data: {SURVEY_CITE}",
                "one open-plan lab of about 21 x 18 m, 12 fixed BLE receivers (anchors), one beacon at 125 positions, "
                "mean RSSI of about 3,500 packets per link (1,500 links), transmit power unknown"
                + (f"; quick: one beacon position in {every} ({125 // every + (125 % every > 0)} positions)"
                   if every > 1 else ""),
                "room: the data set's floor plan (`rfir import floorplan`, walls 3 m high, concrete floor and ceiling; "
                "desks and people not modelled), surfels `rfir mesh-gaussians --preset room`",
                "protocols (`rfir import csv`, seed 0): random: the file's split column (25 of 125 positions, all "
                "their links); held-out area: `--split block-tx:6` (the beacon positions binned in 6 m squares, "
                "whole squares test until 20 % of the links); unseen anchors: `--split holdout-rx:2` (every link of "
                "2 of the 12 receivers test)",
                "rfir: the physical room model (docs/physics.md), rf-fit's defaults (device gains and residual terms "
                "(device patterns, clutter field, kriging; docs/physics.md 8.15) chosen by validation on the training "
                "links, each fit's log says which; links weighted by their packet count and spread; no radio-map "
                "cache: rf_fit.room.map_visibility = false)"
                + (f", {_measured_fit_sets(r)['rf_fit.physical.iterations']} steps" if r.quick else ""),
                "log-distance, multi-wall, nearest links: fitted on the same training links (rfir's predict JSON)",
                "ray tracing (ITU materials): Sionna RT (`scripts/baseline_raytrace.py`, `rfir simulate`'s rssi physics, "
                "configs/simulate.toml; the 12 receivers solved as sources, reciprocity) on the floor plan's mesh with "
                "each label's ITU material (walls concrete of the plan's thickness, floor and ceiling concrete 0.2 m), "
                "plus one system gain fitted on the training links (their mean residual: it stands for the unknown "
                "transmit power and antenna gains)",
                _raytrace_note(sionna),
                _diagnose_note(r, report)]
    _lab_rows(r, t)
    _flat_rows(r, t)
    return t


# The measured target's second survey (tests/data/rtt_lab/README.md): Wi-Fi RTT RSS in a lab hall, 6 access
# points (rx, rx_id), a phone walked along two lines (tx, tx_id: 168 cells of 0.25 m), the walls near the
# lines digitised from the data set's plan.
LAB = Path("tests/data/rtt_lab")
LAB_CITE = ("*Indoor-localization-data-set* (H. Yu, C. She, Y. Hu, G. Wang, R. Wang, B. Vucetic, Y. Li; "
            "arXiv:2405.13339, 2024), Laboratory scenario, MIT licence; source, citation and the derived files: "
            "[tests/data/rtt_lab/README.md](../../tests/data/rtt_lab/README.md)")
LAB_PROTOCOLS = (("random", None, "random 20 % of phone positions"),
                 ("area", "block-tx:6", "held-out area"),
                 ("anchors", "holdout-rx:2", "unseen access points"))


def _lab_rows(r: Plan, t: Table) -> None:
    """The lab-hall survey's rows (quick: every measured_lab_every_tx-th phone position) and notes; ray tracing
    in the full variant only (its sweep would take the quick variant past its budget)."""
    every = int(r.sizes.get("measured_lab_every_tx", 1))
    surveys, scene = _survey_data(r, "measured_lab", LAB / "lab_links.csv", LAB / "lab_walls.csv", every,
                                  LAB_PROTOCOLS)
    sweep = None
    if not r.quick:
        sweep = M.raytrace_sweep(r, "measured_lab", r.data / "measured_lab" / "room.ply", surveys["random"])
    sionna = {}
    for name, _, text in LAB_PROTOCOLS:
        ours = M.rfir_rssi(r, f"measured_lab_{name}", scene, surveys[name], "random", _measured_fit_sets(r))
        cells = {"rfir": ours.cell(),
                 "log-distance": ours.metric("baseline_log_distance_mae_db"),
                 "multi-wall": ours.metric("baseline_multiwall_mae_db"),
                 "nearest links": ours.metric("baseline_nearest_links_mae_db")}
        if sweep is not None:
            sionna[name] = M.raytrace_gain(r, f"measured_lab_{name}", *sweep, surveys[name])
            cells["ray tracing (ITU materials)"] = sionna[name].cell("metrics.mae_db")
            cells["ray tracing (calibrated)"] = sionna[name].cell("metrics.calibrated_mae_db")
        t.add(_measured_label(surveys[name], name, text, "lab hall (Wi-Fi)", "access points"), cells)
    t.notes += [f"lab hall data: {LAB_CITE}",
                "lab hall: an open hall of about 25 x 9 m around a block of rooms, 6 Google Wifi access points "
                "(anchors), two phones walked five times along a line on either side of the block; Wi-Fi RTT RSS "
                "averaged in 0.25 m cells (168 positions, 1,008 links, median 48 samples per link); channel, "
                "heights and transmit power not given (assumed 5.2 GHz, 1.0 / 1.2 m, 20 dBm)"
                + (f"; quick: one position in {every} ({168 // every + (168 % every > 0)} positions)"
                   if every > 1 else ""),
                "lab hall room: 18 walls near the walked lines digitised from the data set's plan (registered by "
                "its six AP markers; stair core and thick walls concrete 0.2 m, room partitions plasterboard "
                "0.1 m), walls 3 m high, concrete floor and ceiling; the hall's south part, furniture and people "
                "not modelled; protocols and rfir's settings as above (held-out area `--split block-tx:6`, unseen "
                "access points `--split holdout-rx:2`)",
                "lab hall ray tracing: " + ("as above, the 6 access points solved as sources" if not r.quick else
                                            "not run in the quick variant (the sweep takes minutes)")]
    if sionna:
        note = _raytrace_note(sionna)
        t.notes.append(lambda: "lab hall " + note())


# The measured target's third group: the measured-like flat (docs/simulate.md), a BLE survey simulated by Sionna RT
# with what the real ones showed (device gains and patterns, fading, three channels averaged, furniture missing from
# the plan, walls a few cm off), scored like them: do its margins predict the real surveys' ones?
FLAT_PROTOCOLS = (("random", "random 20 % of links"), ("room", "held-out room (bedroom)"),
                  ("rx", "unseen anchors"))


def _flat_rows(r: Plan, t: Table) -> None:
    """The measured-like flat's rows (quick: a coarser grid of positions) and notes; no ray-tracing columns (the
    data are Sionna RT's own)."""
    folder = r.data / "measured_flat"
    sim, ml = folder / "sim", folder / "ml"
    grid = r.sizes.get("measured_flat_rx_grid")
    sets = ["--set", f"simulate.rssi.scenes.flat.rx_grid=[{grid[0]},{grid[1]}]"] if grid else []
    r.step("data__measured_flat_sim", [r.rfir, "--seed", "0", *sets, "simulate", "flat", f"{sim}/", "--no-photos",
                                       "--task", "rssi"], f"{sim}/")
    files = {name: ml / f"measurements_{name}.h5" for name, _ in FLAT_PROTOCOLS}
    plan = ml / "floorplan" / "flat_floorplan.ply"
    r.step("data__measured_flat", [r.python, str(M.SCRIPTS / "measured_like.py"), f"{sim}/", f"{ml}/", "--seed", "0"],
           f"{ml}/")
    scene = folder / "plan_scene.h5"
    r.step("data__measured_flat_surfels", [r.rfir, "mesh-gaussians", str(plan), "-o", str(scene), "--preset", "room"],
           scene)
    for name, text in FLAT_PROTOCOLS:
        ours = M.rfir_rssi(r, f"measured_flat_{name}", scene, files[name], "random", _measured_fit_sets(r))
        t.add(_flat_label(files[name], name, text),
              {"rfir": ours.cell(), "log-distance": ours.metric("baseline_log_distance_mae_db"),
               "multi-wall": ours.metric("baseline_multiwall_mae_db"),
               "nearest links": ours.metric("baseline_nearest_links_mae_db")})
    t.notes += ["measured-like flat: `rfir simulate flat` (Sionna RT; a furnished flat of about 9 x 7 m, 6 receivers high, "
                "positions at table height; each link's power the mean over BLE's three advertising channels) turned by "
                "`python scripts/measured_like.py --seed 0` into a survey with what real ones have (docs/simulate.md: "
                "a gain per device, a pattern per device about a random boresight, log-normal fading 2.5 dB, interior "
                "walls a few cm off, furniture missing from the floor plan); its floor plan's surfels `--preset room`; "
                "rfir's settings as above; no ray-tracing columns (the data are the ray tracer's own)"
                + (f"; quick: positions on a {grid[0]} x {grid[1]} grid" if grid else "")]


def _flat_label(meas: Path, name: str, text: str) -> Callable[[], str]:
    """A measured-like flat row's label read from its file: the test links, positions or receivers."""
    def label() -> str:
        import numpy as np

        from rfir_core.artifacts import read_artifact

        a = read_artifact(meas, "measurements")
        test = np.asarray(a["split"]) == 1
        tx, rx = np.asarray(a["tx_id"]), np.asarray(a["rx_id"])
        held = {"random": f"{int(test.sum())} of {test.size} links",
                "room": f"{np.unique(tx[test]).size} of {np.unique(tx).size} positions",
                "rx": f"{np.unique(rx[test]).size} of {np.unique(rx).size} receivers"}[name]
        return f"measured-like flat (simulated), {text} ({held})"
    return label


def _raytrace_note(results: dict) -> Callable[[], str]:
    """A note on the calibrated ray tracing: its grid and, per protocol, the set it chose and the fitted gains."""
    def note() -> str:
        chosen = []
        for name, res in results.items():
            d = res.data()
            chosen.append(f"{name}: {d['calibrated']['chosen']} (gain {d['calibrated']['system_gain_db']:+.1f} dB; "
                          f"ITU {d['itu']['system_gain_db']:+.1f} dB)")
        grid = [g["name"] for g in results[next(iter(results))].data()["calibrated"]["grid"]]
        return ("ray tracing (calibrated): the same with the walls' ITU material and one wall thickness chosen by the "
                f"training links' MAE (after each set's own system gain) from {len(grid)} sets ("
                + ", ".join(grid) + "; plan: each wall's thickness in the floor plan; metal once, opaque at any "
                "thickness); chosen: " + "; ".join(chosen) + ". Both columns' wall time is the whole sweep (every set "
                "solved once, shared by the rows) plus the scoring")
    return note
