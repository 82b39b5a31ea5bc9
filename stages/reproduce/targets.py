"""The reproduce targets: which data each makes, which rows and methods its table has; TARGETS names them all
(the measured target, two measured surveys and the measured-like flat, is in measured_target.py).

Sizes (full / quick; fit steps, surfel spacing and baseline budgets in configs/reproduce.toml):
- data: Sionna RT as `rfir simulate` makes it / physical optics (lego, h-target) or a small
  Sionna classroom; geometry for rfir and the WRF-GS-style field: surfels on the true mesh
  (`rfir mesh-gaussians`).
- rfir: the physical model (RCS, wideband) and the room model (RSSI) with their configured step counts /
  30 steps (quick).
- NeRF2- and WRF-GS-style fields: a wall-clock budget of a few minutes each / one epoch.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from . import methods as M
from rfir_core.config import resolve_config
from rfir_core.errors import ConfigError

from .measured_target import target_measured
from .plan import Plan, default_dirs
from .tables import Cell, Table

NOT_EDITABLE = "cannot edit: retrain on new measurements"
SINGLE_FREQ = "not run: single-frequency implementation"
UNSEEN_FREQ = "not run: predicts only the frequency it was trained on"


def _simulate(r: Plan, name: str, scene: str, sets: dict, args: list[str] = ()) -> Path:
    """`rfir simulate`: measurements, the true mesh and (unless --no-photos) photos with their cameras."""
    folder = r.data / name
    meas = folder / "measurements.h5"
    also = [folder / "meshes" / f"{scene}_gt.ply"]
    if "--no-photos" not in args:
        also += [f"{folder / 'images'}/", folder / "cameras.h5"]
    r.step(f"data__{name}", [r.rfir, *M.set_args(sets), "simulate", scene, str(folder), *args], meas, also)
    return meas


def _surfels(r: Plan, name: str, scene: str, spacing: float, object_cells: int = 0) -> Path:
    """Surfels of the scene's true mesh; object_cells > 0 tiles each labelled object at
    min(spacing, its size / object_cells) and the mesh's rectangles as cells (`--rectangles`; rooms)."""
    out = r.data / name / "scene.h5"
    mesh = r.data / name / "meshes" / f"{scene}_gt.ply"
    cells = ["--object-cells", str(object_cells), "--rectangles", "--drop-contact-faces"] if object_cells else []
    r.step(f"data__{name}_surfels", [r.rfir, "mesh-gaussians", str(mesh), "-o", str(out), "--spacing", f"{spacing:g}",
                                     *cells], out)
    return out


def _rcs_sets(quick: bool, freqs: list[float], ranges: list[float]) -> dict:
    sets = {"simulate.rcs.freqs_hz": "[" + ",".join(f"{f:g}" for f in freqs) + "]",
            "simulate.rcs.ranges_m": "[" + ",".join(f"{x:g}" for x in ranges) + "]"}
    if quick:
        sets.update({"simulate.rcs_backend": "po", "simulate.rcs.aspect_step_deg": 6.0})
    return sets


def _sizes(r: Plan) -> dict:
    """The variant's sizes of configs/reproduce.toml (baseline_epochs 0: no cap)."""
    s = r.sizes
    return {"spacing": s["surfel_spacing_m"], "minutes": s["baseline_minutes"],
            "rssi_minutes": s["rssi_minutes"], "epochs": s["baseline_epochs"] or None}


def _fit_sets(r: Plan, extra: dict | None = None) -> dict:
    """rf-fit settings of every rfir fit of the variant: the physical model's Adam steps (configs/reproduce.toml
    `iterations`; its starts get a fifth of them, at least 10) plus `extra`."""
    n = int(r.sizes["iterations"])
    return {"rf_fit.physical.iterations": n, "rf_fit.physical.start_iterations": max(10, n // 5), **(extra or {})}


def _object_data(r: Plan, obj: str, freqs: list[float], ranges: list[float], tag: str = "") -> tuple[Path, Path]:
    s = _sizes(r)
    name = f"{obj}{tag}"
    meas = _simulate(r, name, obj, _rcs_sets(r.quick, freqs, ranges), ["--no-photos", "--task", "rcs"])
    return meas, _surfels(r, name, obj, s["spacing"])


def _rcs_row(r: Plan, table: Table, label: str, obj: str, meas: Path, scene: Path, protocol: str,
             freq_hz: float, freq_index: int) -> None:
    s = _sizes(r)
    ours = M.rfir_rcs(r, label, scene, meas, protocol, freq_hz, _fit_sets(r))
    near = ours.metric("baseline_nearest_mae_db", "baseline_nearest_range_mae_db")
    lin = ours.metric("baseline_linear_mae_db", "baseline_linear_range_mae_db")
    table.add(f"{obj} {freq_hz / 1e9:g} GHz, {protocol}", {
        "rfir": ours.cell(),
        "NeRF2-style": M.nerf2(r, label, meas, "rcs", protocol, s["minutes"], freq_index, s["epochs"]),
        "WRF-GS-style": M.wrfgs(r, label, meas, scene, "rcs", protocol, s["minutes"], freq_index, s["epochs"]),
        "nearest aspect": near, "linear interpolation": lin})


RCS_METHODS = ["rfir", "NeRF2-style", "WRF-GS-style", "nearest aspect", "linear interpolation"]


def target_rcs(r: Plan) -> Table:
    """The paper's RCS table (lego and car at 2.4 and 5.8 GHz, even/odd aspects) plus harder protocols."""
    t = Table("RCS: monostatic, 3 m, train/test protocols of rfir_stages.model.split_protocols", RCS_METHODS)
    freqs = [2.4e9] if r.quick else [2.4e9, 5.8e9]
    objects = ["lego"] if r.quick else ["lego", "car"]
    for obj in objects:
        meas, scene = _object_data(r, obj, freqs, [3.0])
        for k, f in enumerate(freqs):
            _rcs_row(r, t, f"rcs_{obj}_{f / 1e9:g}_data", obj, meas, scene, "data", f, k)
    meas, scene = _object_data(r, "lego", freqs, [3.0])
    for protocol in ("every-10", "sector:45:135"):
        _rcs_row(r, t, f"rcs_lego_2.4_{protocol.replace(':', '_')}", "lego", meas, scene, protocol, 2.4e9, 0)
    t.notes += ["data: physical optics, 6-degree aspects (quick)" if r.quick else
                "data: Sionna RT (geometric optics + diffuse; `rfir simulate`), 1-degree aspects; the physics rows "
                "(physical-optics data) are the rcs-po table",
                "protocols: data: even/odd aspects (odd test); every-10: aspects with index divisible by 10 train; "
                "sector: aspects in [45, 135) degrees test",
                "nearest aspect / linear interpolation: copy or interpolate the training aspects (rfir's predict JSON)",
                "NeRF2-style / WRF-GS-style: our implementations (docs/baselines.md), trained on the same rows"]
    return t


PO_PROTOCOLS = (("data", "even/odd aspects"), ("every-10", "every 10th aspect trains"),
                ("every-30", "every 30th aspect trains"), ("sector:45:135", "sector 45-135 deg held out"))


def _po_data(r: Plan, obj: str) -> tuple[Path, Path]:
    """Physical-optics data of an object at 2.4 and 5.8 GHz (quick: the rcs target's lego data, 2.4 GHz, 3 m,
    6-degree aspects) and surfels on its true mesh."""
    if r.quick:
        return _object_data(r, obj, [2.4e9], [3.0])
    ranges = "[" + ",".join(f"{x:g}" for x in r.sizes["po_ranges_m"]) + "]"
    meas = _simulate(r, f"{obj}_po", obj, {"simulate.rcs.freqs_hz": "[2.4e9,5.8e9]", "simulate.rcs.ranges_m": ranges},
                     ["--no-photos", "--task", "rcs", "--rcs-backend", "po"])
    return meas, _surfels(r, f"{obj}_po", obj, _sizes(r)["spacing"])


# The unseen-range rows of the rcs-po target: an interior range of the data held out (the physical model
# predicts any range; the simple baselines copy or interpolate the measured ranges).
PO_HELD_OUT_RANGE_M = 3.0


def _po_range_row(r: Plan, table: Table, obj: str, meas: Path, scene: Path, physical: dict) -> None:
    """The row `range:R` (R = PO_HELD_OUT_RANGE_M) at 2.4 GHz: the other ranges train, every aspect at R
    tests; the simple baselines copy or interpolate in range at the same aspect."""
    s = _sizes(r)
    protocol = f"range:{PO_HELD_OUT_RANGE_M:g}"
    label = f"rcs_po_{obj}_2.4_{protocol.replace(':', '_')}"
    ours = M.rfir_rcs(r, label, scene, meas, protocol, 2.4e9, physical)
    table.add(f"{obj} 2.4 GHz, {PO_HELD_OUT_RANGE_M:g} m held out", {
        "rfir": ours.cell(),
        "NeRF2-style": M.nerf2(r, label, meas, "rcs", protocol, s["minutes"], 0, s["epochs"]),
        "WRF-GS-style": M.wrfgs(r, label, meas, scene, "rcs", protocol, s["minutes"], 0, s["epochs"]),
        "nearest aspect": ours.metric("baseline_nearest_range_mae_db"),
        "linear interpolation": ours.metric("baseline_linear_range_mae_db")})


def _unseen_freq_cell(res: M.Result, key: str) -> Callable[[], Cell]:
    """A simple baseline on the unseen-frequency row: it has no 5.8 GHz training rows to copy; predict's
    JSON scores it with the 5.8 GHz training rows the fit never saw, shown as a reference in the note."""
    def read() -> Cell:
        value = res.data()["metrics"].get(key)
        ref = "" if value is None else f" ({value:.2f} with the 5.8 GHz training rows rfir was not given)"
        return Cell(note="not run: no measurement at 5.8 GHz to copy" + ref)
    return read


def target_rcs_po(r: Plan) -> Table:
    """The physics rows: RCS on physical-optics data (lego; trio: a metal dihedral, a wooden block and a
    glass pane; car: a metal body; quick: the lego only), rfir's physical model against the fields and the
    simple baselines, at 2.4 GHz, the unseen-range row (3 m held out; full variant) and the unseen-frequency
    row (fit 2.4 GHz, predict 5.8 GHz)."""
    t = Table("RCS on physical-optics data: monostatic, 2.4 GHz unless stated, train/test protocols of "
              "rfir_stages.model.split_protocols", RCS_METHODS)
    s = _sizes(r)
    physical = _fit_sets(r)
    # the unseen-range rows (full variant only) need the held-out range and another one to train on
    ranges_m = [] if r.quick else [float(x) for x in r.sizes["po_ranges_m"]]
    range_rows = PO_HELD_OUT_RANGE_M in ranges_m and len(ranges_m) > 1
    for obj in ["lego"] if r.quick else ["lego", "trio", "car"]:
        meas, scene = _po_data(r, obj)
        for protocol, text in PO_PROTOCOLS[3:] if r.quick else PO_PROTOCOLS:
            label = f"rcs_po_{obj}_2.4_{protocol.replace(':', '_')}"
            ours = M.rfir_rcs(r, label, scene, meas, protocol, 2.4e9, physical)
            full = Cell(note="full run only")
            t.add(f"{obj} 2.4 GHz, {text}", {
                "rfir": ours.cell(),
                "NeRF2-style": full if r.quick else M.nerf2(r, label, meas, "rcs", protocol, s["minutes"], 0,
                                                            s["epochs"]),
                "WRF-GS-style": full if r.quick else M.wrfgs(r, label, meas, scene, "rcs", protocol, s["minutes"], 0,
                                                             s["epochs"]),
                "nearest aspect": ours.metric("baseline_nearest_mae_db"),
                "linear interpolation": ours.metric("baseline_linear_mae_db")})
        if r.quick:
            continue
        if range_rows:
            _po_range_row(r, t, obj, meas, scene, physical)
        # the even/odd fit at 2.4 GHz, predicted at 5.8 GHz on the odd aspects
        fit = f"rcs_po_{obj}_2.4_data"
        res = M.rfir_predict_rcs(r, f"rcs_po_{obj}_2.4to5.8_data", r.data / "fits" / f"{fit}.h5", meas,
                                 f"{fit}__rfir_fit", [5.8e9])
        t.add(f"{obj}, fit 2.4 GHz, predict 5.8 GHz (odd aspects)", {
            "rfir": res.cell(), "NeRF2-style": Cell(note=UNSEEN_FREQ), "WRF-GS-style": Cell(note=UNSEEN_FREQ),
            "nearest aspect": _unseen_freq_cell(res, "baseline_nearest_mae_db"),
            "linear interpolation": _unseen_freq_cell(res, "baseline_linear_mae_db")})
    ranges = "3 m" if r.quick else ", ".join(f"{x:g}" for x in r.sizes["po_ranges_m"]) + " m"
    t.notes += [
        "data: physical optics (`rfir simulate lego|trio|car --no-photos --rcs-backend po`: coherent surface currents "
        "with up to three bounces (`simulate.po.max_bounces`), ITU materials as slabs, 40-degree horns; docs/po.md), "
        + ("6-degree aspects, 3 m (quick)" if r.quick else f"1-degree aspects, ranges {ranges}, 2.4 and 5.8 GHz")
        + "; unlike Sionna RT's geometric optics + diffuse, its lobes narrow with frequency, so these are the "
        "physics rows (the rcs table is on Sionna data)",
        "trio: a metal dihedral (3 mm sheets), a wooden block and a 6 mm glass pane; lego: plasterboard bricks"
        + ("" if r.quick else "; car: a metal body"),
        "rfir: the physical model (per-object materials with eps_r, sigma, "
        "thickness and S on surfel physical optics, the residual chosen by validation; docs/physics.md) on "
        f"surfels of the true mesh ({s['spacing'] * 100:g} cm), fitted at 2.4 GHz on the protocol's training rows"
        + (f" ({physical['rf_fit.physical.iterations']} steps, quick)" if r.quick else ""),
        "protocols: even/odd: odd aspects test (each 1 degree from a training one); every Nth: aspects with index "
        "divisible by N train; sector: aspects in [45, 135) degrees test; scored on the test rows at every range",
        "fit 2.4 GHz, predict 5.8 GHz: the even/odd fit (2.4 GHz rows only) predicts the odd aspects at 5.8 GHz; "
        "nearest / linear have no 5.8 GHz training rows to copy (their figure with those rows in brackets)",
        "on dense rows (even/odd) interpolating the measurement is hard to beat: the target there is rfir within "
        "0.3 dB of the best; where the data do not cover the question (every Nth, sector, unseen frequency) rfir "
        "should be lowest",
        "nearest aspect / linear interpolation: copy or interpolate the training aspects (rfir's predict JSON); "
        "NeRF2-style / WRF-GS-style: our implementations (docs/baselines.md), trained on the same rows"]
    if r.quick:
        return t
    held = f"{PO_HELD_OUT_RANGE_M:g} m"
    if range_rows:
        others = ", ".join(f"{x:g}" for x in ranges_m if x != PO_HELD_OUT_RANGE_M)
        t.notes.insert(-2, f"{held} held out: the other ranges ({others} m) train, every aspect at {held} tests; "
                       "nearest / linear there copy the nearest training range or interpolate linearly in range, "
                       "at the same aspect (between measured ranges interpolation is hard to beat: the target "
                       "there is rfir within 0.3 dB of the best)")
    else:
        t.notes.insert(-2, f"no unseen-range rows: the data's ranges ({ranges}) need {held} and another range")
    return t


def target_extrapolation(r: Plan) -> Table:
    """Range extrapolation: train at 2, 2.5, 4, 4.5, 5 m, test at 3 m (lego, 2.4 GHz)."""
    t = Table("Range extrapolation: lego 2.4 GHz, 3 m held out",
              ["rfir", "NeRF2-style", "WRF-GS-style", "nearest range", "linear in range"])
    ranges = [2.0, 3.0, 4.0] if r.quick else [2.0, 2.5, 3.0, 4.0, 4.5, 5.0]
    meas, scene = _object_data(r, "lego", [2.4e9], ranges, tag="_ranges")
    s = _sizes(r)
    label = "extrap_lego_2.4_range3"
    ours = M.rfir_rcs(r, label, scene, meas, "range:3", 2.4e9, _fit_sets(r))
    t.add("lego 2.4 GHz, test 3 m", {
        "rfir": ours.cell(),
        "NeRF2-style": M.nerf2(r, label, meas, "rcs", "range:3", s["minutes"], 0, s["epochs"]),
        "WRF-GS-style": M.wrfgs(r, label, meas, scene, "rcs", "range:3", s["minutes"], 0, s["epochs"]),
        "nearest range": ours.metric("baseline_nearest_range_mae_db"),
        "linear in range": ours.metric("baseline_linear_range_mae_db")})
    t.notes.append(f"training ranges: {', '.join(f'{x:g}' for x in ranges if x != 3.0)} m")
    return t


def _wideband_freqs(meas: Path, every: int) -> str:
    """Every `every`-th frequency of the measurements, read when the step runs (a shell substitution)."""
    return f"$(python -m rfir_stages.reproduce freqs {meas} {every})"


def target_wideband(r: Plan) -> Table:
    """h-target, 160 MHz around 5.8 GHz (physical optics): rfir's physical model on the band
    (docs/guide/rcs-sweep.md) beside the simple baselines."""
    t = Table("Wideband: h-target 5.72-5.88 GHz, even/odd aspects", ["rfir", "NeRF2-style", "WRF-GS-style",
              "nearest aspect", "linear interpolation"])
    sets = {"simulate.rcs_backend": "po"}
    if r.quick:
        sets.update({"simulate.wideband.aspect_step_deg": 10.0, "simulate.wideband.num_freqs": 64})
    meas = _simulate(r, "htarget", "h-target", sets, ["--no-photos", "--task", "wideband"])
    scene = _surfels(r, "htarget", "h-target", 0.06 if r.quick else 0.03)
    fits = r.data / "fits"
    # one material for the one-object scene (its labels and one global material are the same fit)
    phys = fits / "wideband_htarget.h5"
    phys_sets = {"rf_fit.physical.sharing": "global"}
    if r.quick:
        phys_sets.update({"rf_fit.physical.iterations": 60, "rf_fit.physical.start_iterations": 15})
    t_phys = r.step("wideband_htarget__rfir_fit", [r.rfir, "--seed", "0", *M.set_args(phys_sets), "rf-fit",
                                                  str(scene), str(meas), "-o", str(phys)], phys)
    freqs = _wideband_freqs(meas, 1 if r.quick else 8)
    j = r.json_path("wideband_htarget__rfir")
    t_pred = r.step("wideband_htarget__rfir_predict", [
        r.rfir, "--seed", "0", "predict", "rcs", str(phys), "--measurements", str(meas), "--freqs", freqs,
        "-o", str(fits / "wideband_pred.h5"), "--plots", str(r.out / "plots" / "wideband"),
        "--results", str(j)], j)
    res = M.Result(r, j, t_pred, t_phys)
    t.add("h-target wideband" + (" (every 8th frequency scored)" if not r.quick else ""),
          {"rfir": res.cell(), "NeRF2-style": Cell(note=SINGLE_FREQ), "WRF-GS-style": Cell(note=SINGLE_FREQ),
           "nearest aspect": res.metric("baseline_nearest_mae_db"),
           "linear interpolation": res.metric("baseline_linear_mae_db")})
    t.notes.append("rfir: the physical model on the band (materials, frequency an input; docs/physics.md)")
    return t


def _classroom(r: Plan) -> tuple[Path, Path]:
    """The room's RSSI data (full: with the photos the geom-mesh baseline needs) and its surfels."""
    sets = {} if not r.quick else {"simulate.rssi.tx_grid": "[2,2]", "simulate.rssi.rx_grid": "[6,5]"}
    meas = _simulate(r, "classroom", "classroom", sets, ["--no-photos"] if r.quick else [])
    # the walls at 0.8 m, each piece of furniture about 12 surfels across: reflections off desks and chairs
    # near the receivers need their extent (docs/physics.md)
    return meas, _surfels(r, "classroom", "classroom", 1.2 if r.quick else 0.8, 6 if r.quick else 12)


def _geom_mesh(r: Plan) -> Path:
    """Photos -> calibrate -> geom -> the TSDF mesh the ray-tracing baseline runs on."""
    meas, _ = _classroom(r)
    folder = meas.parent
    calib, scene = folder / "calib.h5", folder / "geom_scene.h5"
    r.step("data__classroom_calibrate", [r.rfir, "calibrate", str(folder / "images"), "-o", str(calib), "--poses",
                                         str(folder / "cameras.h5"), "--intrinsics-from", str(folder / "cameras.h5")],
           calib)
    mesh = folder / "geom_scene_mesh.ply"
    r.step("data__classroom_geom", [r.rfir, "geom", str(calib), "-o", str(scene)], scene, [mesh])
    return mesh


def _rssi_physical(r: Plan, label: str, scene: Path, meas: Path, split: str, extra: dict | None = None,
                   tag: str = "_physical") -> M.Result:
    """rfir's RSSI model (the physical room model) on the classroom; one step shared by the targets."""
    return M.rfir_rssi(r, label + tag, scene, meas, split, _fit_sets(r, extra))


def target_rssi(r: Plan) -> Table:
    """Classroom RSSI (Sionna RT, 2.4 GHz): random 80/20 links and 4 unseen transmitters."""
    t = Table("RSSI: classroom 2.4 GHz", ["rfir", "NeRF2-style", "WRF-GS-style", "ray tracing (geom mesh)",
                                          "ray tracing (geom mesh, calibrated)", "ray tracing (true mesh)",
                                          "ray tracing (true mesh, calibrated)", "log-distance", "multi-wall",
                                          "nearest links"])
    meas, scene = _classroom(r)
    s = _sizes(r)
    splits = ["random"] if r.quick else ["random", "holdout_tx"]
    minutes = s["rssi_minutes"]
    mesh = r.data / "classroom" / "meshes" / "classroom_gt.ply"
    calibrated = (r.sizes["calibrated_iterations"], r.sizes["calibrated_links"])
    for split in splits:
        label = f"rssi_classroom_{split}"
        ours = _rssi_physical(r, label, scene, meas, split)
        row = {"rfir": ours.cell(),
               "NeRF2-style": M.nerf2(r, label, meas, "rssi", split, minutes, 0, s["epochs"]),
               "WRF-GS-style": M.wrfgs(r, label, meas, scene, "rssi", split, minutes, 0, s["epochs"]),
               "log-distance": ours.metric("baseline_log_distance_mae_db"),
               "multi-wall": ours.metric("baseline_multiwall_mae_db"),
               "nearest links": ours.metric("baseline_nearest_links_mae_db"),
               "ray tracing (true mesh, calibrated)": M.raytrace_calibrated(r, label + "_truemesh", mesh, meas, split,
                                                                            *calibrated)}
        if split == "random":
            row["ray tracing (true mesh)"] = M.raytrace(r, label + "_truemesh", mesh, meas)
            row["ray tracing (geom mesh)"] = (Cell(note="full run only") if r.quick
                                              else M.raytrace(r, label + "_geommesh", _geom_mesh(r), meas))
            row["ray tracing (geom mesh, calibrated)"] = (
                Cell(note="full run only") if r.quick
                else M.raytrace_calibrated(r, label + "_geommesh", _geom_mesh(r), meas, split, *calibrated))
        else:
            row["ray tracing (true mesh)"] = row["ray tracing (geom mesh)"] = Cell(note="random split only")
            row["ray tracing (geom mesh, calibrated)"] = Cell(note="random split only")
        t.add(f"classroom, {'random 80/20' if split == 'random' else '4 unseen Tx'}", row)
    t.notes += ["rfir: the physical room model (paths through and off the surfaces, fitted physical materials per "
                "object class; docs/physics.md)",
                "log-distance, multi-wall, nearest links: fitted on the same training rows (rfir's predict JSON)",
                "ray tracing: Sionna RT, every face concrete (a user's guess; the true materials are mixed); calibrated: "
                "eps_r and sigma per object class fitted by gradient descent through Sionna's differentiable solver on "
                "a subsample of the training links, slab thickness kept at the guess; on the geom mesh (no labels) one "
                "global material (docs/baselines.md)",
                "the geom mesh comes from `rfir calibrate` + `rfir geom` on the simulator's photos of the room",
                "ray tracing on the true mesh uses the simulator's own geometry: an upper bound no user has"]
    return t


ABLATION = ["rfir", "physics only (no residual)", "single bounce", "one material", "without diffuse"]


def target_ablation(r: Plan) -> Table:
    """The physical model without each of its terms: the residual, the double bounces, a material per
    object, the diffuse term (RCS on physical-optics data; RSSI on the classroom)."""
    t = Table("Ablation: the physical model's terms", ABLATION)
    obj, protocol = ("lego", "sector:45:135") if r.quick else ("trio", "every-10")
    meas, scene = _po_data(r, obj)
    tag = protocol.replace(":", "_")

    def fit(name: str, extra: dict) -> Cell:
        return M.rfir_rcs(r, f"ablation_{obj}_{tag}_{name}", scene, meas, protocol, 2.4e9, _fit_sets(r, extra)).cell()
    one = (Cell(note="one object class (bricks): one material already") if obj == "lego"
           else fit("one_material", {"rf_fit.physical.sharing": "global"}))
    t.add(f"{obj} 2.4 GHz RCS (physical optics), {protocol}", {
        "rfir": M.rfir_rcs(r, f"rcs_po_{obj}_2.4_{tag}", scene, meas, protocol, 2.4e9, _fit_sets(r)).cell(),
        "physics only (no residual)": fit("no_residual", {"rf_fit.physical.residual": "off"}),
        "single bounce": fit("single_bounce", {"rf_fit.physical.second_order": "false"}),
        "one material": one,
        "without diffuse": Cell(note="RSSI only (the RCS model fits S per material)")})
    if not r.quick:
        cmeas, cscene = _classroom(r)
        label = "rssi_classroom_random"
        t.add("classroom RSSI, random 80/20", {
            "rfir": _rssi_physical(r, label, cscene, cmeas, "random").cell(),
            "physics only (no residual)": Cell(note="the room model has no residual"),
            "single bounce": _rssi_physical(r, label, cscene, cmeas, "random", {"rf_fit.room.max_order": 1},
                                            "_single_bounce").cell(),
            "one material": _rssi_physical(r, label, cscene, cmeas, "random", {"rf_fit.room.sharing": "global"},
                                           "_one_material").cell(),
            "without diffuse": _rssi_physical(r, label, cscene, cmeas, "random", {"rf_fit.room.diffuse": "false"},
                                              "_no_diffuse").cell()})
    t.notes += ["rfir: the physical model with every term (docs/physics.md); each other column "
                "turns one term off and refits on the same rows",
                "RCS data: physical optics (rcs-po target; quick: the rcs target's lego, 3 m, 6-degree aspects); "
                "every-10: aspects with index divisible by 10 train; sector: aspects in [45, 135) degrees test",
                "single bounce: RCS rf_fit.physical.second_order = false (no dihedral flash); RSSI "
                "rf_fit.room.max_order = 1",
                "one material: rf_fit.physical.sharing / rf_fit.room.sharing = global"]
    return t


def _edit_row(r: Plan, t: Table, name: str, rf: Path, before: Path, after: Path, ops: list[str]) -> None:
    j = r.json_path(f"edit_{name}__rfir")
    step = r.step(f"edit_{name}__rfir", [r.python, "scripts/edit_validate.py", str(rf), str(before), str(after),
                                         *ops, "--name", name, "--results", str(j),
                                         "--plots", str(r.out / "plots" / "edit"), "--work", str(r.data / "edit_work")], j)
    res = M.Result(r, j, step)

    def label() -> str:
        d = res.data()
        return (f"{name} (unedited {d['unedited_mae_db']:.2f} dB; ratio {d['mae_ratio']:.2f}; change corr "
                f"{d['change_correlation']:.2f})")
    t.add(label, {"rfir": res.cell("edited_mae_db"), "NeRF2-style": Cell(note=NOT_EDITABLE),
           "WRF-GS-style": Cell(note=NOT_EDITABLE), "ray tracing": Cell(note="not run: the mesh from photos has no "
                                                                           "objects to select")})


def target_edit(r: Plan) -> Table:
    """Edits of a fitted scene checked against the simulator run on the edited scene (issue 9)."""
    t = Table("Edits: MAE of the edited scene's prediction", ["rfir", "NeRF2-style", "WRF-GS-style", "ray tracing"])
    s = _sizes(r)
    rot = "brick_1[6-9]:rotate:0,0,1,45,0,0,0"
    # physical-optics data: the RCS physics rows (Sionna's geometric optics has no lobes for a rotated part to move)
    obj_sets = dict(_rcs_sets(r.quick, [2.4e9], [3.0]), **{"simulate.rcs_backend": "po"})
    before = _simulate(r, "edit_lego", "lego", obj_sets, ["--no-photos", "--task", "rcs"])
    after = _simulate(r, "edit_lego_rotated", "lego", obj_sets, ["--no-photos", "--task", "rcs", "--scene-edit", rot])
    scene = _surfels(r, "edit_lego", "lego", s["spacing"])
    # the default sharing gives the bricks one material (one object class): per-brick materials would fit
    # brick-specific brightness that does not move with a brick
    rf = r.data / "fits" / "edit_lego.h5"
    sets = M.set_args(_fit_sets(r))
    r.step("edit_lego__rfir_fit", [r.rfir, "--seed", "0", *sets, "rf-fit", str(scene), str(before), "-o", str(rf)], rf)
    _edit_row(r, t, "lego_rotate_top", rf, before, after, ["--select", "label:brick_1[6-9]", "--op",
                                                           "rotate:0,0,1,45,0,0,0"])
    if not r.quick:
        meas, scene = _classroom(r)
        _rssi_physical(r, "rssi_classroom_random", scene, meas, "random")
        rf = r.data / "fits" / "rssi_classroom_random_physical.h5"
        for name, edit, ops in (
                ("classroom_remove_whiteboard", "whiteboard:delete", ["--select", "label:whiteboard", "--op", "delete"]),
                ("classroom_move_desk_row", "desk_0[0369]|chair_0[0369]:translate:0,1,0",
                 ["--select", "label:desk_0[0369]", "--op", "translate:0,1,0",
                  "--select", "label:chair_0[0369]", "--op", "translate:0,1,0"]),
                ("classroom_back_wall_metal", "wall_back:material:metal",
                 ["--select", "label:wall_back", "--op", "material:metal"])):
            after = _simulate(r, f"edit_{name}", "classroom", {}, ["--no-photos", "--scene-edit", edit])
            _edit_row(r, t, name, rf, meas, after, ops)
    t.notes += ["rfir: the fit of the unedited scene plus `rfir edit`, scored against the simulator on the "
                "edited scene (target: within 1.5x of the unedited MAE)",
                "lego: physical-optics data, one material for the bricks (one object class); the edit drops the "
                "model's residual, so the edited scene is predicted by the physics alone (docs/guide/edit.md)",
                "NeRF2- and WRF-GS-style fields learn one fixed scene: an edit means new measurements and a new "
                "training run (their time and data, not a prediction)"]
    return t


DIAGNOSE = "diagnose_blind"


def declare_diagnose(r: Plan) -> str:
    """The blind diagnose set (scripts/diagnose_blind.py, docs/guide/diagnose.md): hidden effects in copies of
    simulated data, diagnosed without their answers, scored; it writes its own table to
    OUT/diagnose/diagnose_blind.{md,json} (and a report per case)."""
    out = r.out / "diagnose"
    return r.step(DIAGNOSE, [r.python, str(M.SCRIPTS / "diagnose_blind.py"), "run", str(r.data / "diagnose_blind"),
                             str(out), *(["--quick"] if r.quick else [])],
                  out / "diagnose_blind.md", [out / "diagnose_blind.json"])


FULLWAVE = "fullwave_po"


def declare_fullwave(r: Plan) -> str:
    """The full-wave check of the PO backend (scripts/fullwave_compare.py, docs/po.md): boundary elements
    against `rfir_stages.po` on a 0.3 m PEC plate and a dihedral, 360 aspects at 2.4 GHz; writes
    OUT/fullwave/fullwave_vs_po.{json,png} (curves, gaps by aspect region, timings). Full variant only."""
    out = r.out / "fullwave"
    return r.step(FULLWAVE, [r.python, str(M.SCRIPTS / "fullwave_compare.py"), "--out", str(out), "--aspects", "360",
                             "--plate-n", "16", "--dihedral-n", "12"],
                  out / "fullwave_vs_po.json", [out / "fullwave_vs_po.png"])


def declare(names: list[str], quick: bool, data: Path | None = None, out: Path | None = None,
            overrides: list[str] = ()) -> tuple[Plan, dict[str, tuple[Table, list[str]]]]:
    """The plan of the named targets, the diagnose set and (full variant) the full-wave check (every step,
    inputs linked) and, per
    target, its deferred table and the labels of its steps. data / out default to plan.default_dirs(quick); overrides:
    `reproduce.<full|quick>.<key>=value` settings over configs/reproduce.toml."""
    d, o = default_dirs(quick)
    bad = [o for o in overrides if not o.startswith("reproduce.")]
    if bad:
        raise ConfigError(f"reproduce setting {bad[0]!r}: only reproduce.* keys (configs/reproduce.toml)")
    sizes = resolve_config(overrides=list(overrides))["reproduce"]["quick" if quick else "full"]
    plan = Plan(data or d, out or o, quick=quick, sizes=sizes, overrides=list(overrides))
    tables = {}
    for name in names:
        if name not in TARGETS:
            raise ConfigError(f"unknown reproduce target {name!r} (known: {', '.join(TARGETS)})")
        plan.used = []
        tables[name] = (TARGETS[name](plan), list(plan.used))
    declare_diagnose(plan)
    if not quick:
        declare_fullwave(plan)
    plan.link_inputs()
    return plan, tables


TARGETS = {"rcs": target_rcs, "rcs-po": target_rcs_po, "wideband": target_wideband, "rssi": target_rssi,
           "extrapolation": target_extrapolation, "edit": target_edit, "ablation": target_ablation,
           "measured": target_measured}

# What each table measures, one or two sentences (the results page, docs/results.md, opens each table with it).
ABOUT = {
    "rcs": "Monostatic RCS of the lego and the car on Sionna RT data (geometric optics plus diffuse scattering) at "
           "3 m: even/odd aspects at 2.4 and 5.8 GHz, and on the lego every 10th aspect training and a 90-degree "
           "sector held out.",
    "rcs-po": "The physics rows: monostatic RCS of the lego, the trio (a metal dihedral, a wooden block, a glass "
              "pane) and the car on physical-optics data, dense, sparse and held-out-sector protocols at 2.4 GHz, "
              "and 5.8 GHz predicted from a 2.4 GHz fit (no other method predicts a frequency it was not trained "
              "on).",
    "wideband": "One fit over 160 MHz around 5.8 GHz (the metal h-target, physical optics, even/odd aspects), "
                "scored on every 8th frequency.",
    "rssi": "Received power in a simulated classroom at 2.4 GHz on random 80/20 links and on 4 unseen transmitters, "
            "against the fields, ray tracing on the photo-made and the true mesh (with guessed or calibrated "
            "materials), log-distance and multi-wall.",
    "extrapolation": "RCS at a range no training link had: the lego at 2.4 GHz trained at 2, 2.5, 4, 4.5 and 5 m, "
                     "tested at 3 m.",
    "edit": "A fitted scene edited (a part rotated, an object removed or moved, a wall's material changed) and "
            "predicted, scored against the simulator run on the edited scene; the row label gives the unedited "
            "MAE, the ratio to it and the rank correlation of the predicted with the simulated change.",
    "ablation": "The physical model with one term turned off at a time (residual, double bounces, a material per "
                "object, the diffuse term), refitted on the same rows.",
    "measured": "Two measured surveys (a BLE lab: 12 receivers, 125 beacon positions; a Wi-Fi lab hall: 6 access "
                "points, 168 phone positions): random positions, a held-out area and unseen receivers, against "
                "log-distance, multi-wall and nearest links.",
    DIAGNOSE: "`rfir diagnose` on copies of simulated data with a hidden effect each: whether it names the effect "
              "(or says none is in its catalogue), and the held-out MAE before and after the named correction.",
    FULLWAVE: "The physical-optics backend of `rfir simulate` against a boundary-element (full-wave) solution on a "
              "0.3 m PEC plate and a dihedral, 360 aspects at 2.4 GHz, V polarisation: the gap by aspect region.",
}
