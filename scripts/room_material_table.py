"""The room model's fitted materials against the simulator's: links per label, fitted and true values, target met.

    python scripts/room_material_table.py RF.h5 MEASUREMENTS.h5 [--eps-ranges] [--json OUT.json]

RF.h5 is an rf artifact of `rfir rf-fit` on RSSI data of a scene `rfir simulate` builds (the classroom);
MEASUREMENTS.h5 the file it was fitted on (its scene edits, `simulate.scene_edits`, are applied to the
simulator's materials). For each material (object class: desk_03 and desk_07 are
"desk"): the fit links (training/fit_rows) with a path that reflects off or crosses it, the fewest of
any one object of the class, the fitted |Gamma(0)|, eps_r, sigma and thickness at the fitted
frequency, the simulator's (its ITU-R P.2040 material and slab thickness), and whether issue targets
hold: |Gamma(0)| within 0.1, eps_r within 30 % for dielectrics, a metal fitted as a metal
(|Gamma(0)| >= 0.9); "(concrete)": rf-fit took the material as that tabulated one
(rf_fit.room.tabulated_materials). The |Gamma(0)| range the links allow is read from the artifact when rf-fit ran
with rf_fit.room.reflection_ranges = true. --eps-ranges also scans the same candidate grid with the
same one-standard-error rule (rfir_stages.model.identifiability) and gives the range of eps_r of the
compatible dielectric candidates: whether the links determine eps_r at all. A report, not a stage.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from rfir_stages.simulate.scene_edits import measurement_scene_edits
from rfir_stages.simulate.truth import object_class, true_materials

TARGET_GAMMA = 0.1
TARGET_EPS = 0.3
METAL_GAMMA = 0.9


def links_touching(room, links, label_names: list[str]) -> tuple[np.ndarray, dict]:
    """(links per material [N], {material: fewest links of one object of it}): a path reflects off or crosses it."""
    p = links.paths
    touch = (p.kind > 0).numpy()
    link = np.repeat(p.link.numpy()[:, None], touch.shape[1], 1)[touch]
    patch = p.patch.numpy()[touch]
    mat = room.material_of_patch[patch]
    per_mat = np.array([len(np.unique(link[mat == m])) for m in range(room.num_materials)])
    obj = room.patches.label[patch]
    fewest = {}
    for lab in np.unique(room.patches.label[room.patches.label >= 0]):
        name = label_names[lab] if lab < len(label_names) else str(lab)
        cls = object_class(name)
        n = len(np.unique(link[obj == lab]))
        fewest[cls] = min(fewest.get(cls, n), n)
    return per_mat, fewest


def eps_ranges(links, vals, target_db: np.ndarray, freq_hz: float) -> np.ndarray:
    """[N, 2] eps_r range of the dielectric candidates (sigma below a metal's) the links cannot tell apart
    from the fitted material: identifiability's grid and rule, with the candidates' eps_r kept."""
    from rfir_stages.model.fit_physical import training_predictor
    from rfir_stages.model.identifiability import EPS_R_GRID, SIGMA_1GHZ_GRID, THICKNESS_GRID_M, block_standard_error
    from rfir_stages.model.physical import THICKNESS_M, MaterialParams
    from rfir_stages.model.residual import SE_MARGIN

    n = len(vals.eps_r)
    params = MaterialParams(n, sigma_exponent=vals.sigma_exponent)
    for i in range(n):
        params.set_values(i, eps_r=float(vals.eps_r[i]), sigma_1ghz=float(vals.sigma_1ghz[i]),
                          scattering=float(vals.scattering[i]), thickness_m=float(vals.thickness_m[i]))
    keep = {k: v.detach().clone() for k, v in params.state_dict().items()}
    target = torch.as_tensor(target_db[:, None])
    pred = training_predictor(links, target)
    th_grid = [t for t in THICKNESS_GRID_M if THICKNESS_M[0] <= t <= THICKNESS_M[1]]
    out = np.stack([vals.eps_r.numpy(), vals.eps_r.numpy()], 1)
    with torch.no_grad():
        base = ((pred(params) - target) ** 2)[:, 0]
        for i in range(n):
            for s in sorted({float(vals.scattering[i]), 0.0}):
                for eps in EPS_R_GRID:
                    for sig in SIGMA_1GHZ_GRID[:-1]:               # the last is a metal's: no eps_r
                        for th in th_grid:
                            params.set_values(i, eps_r=eps, sigma_1ghz=sig, scattering=s, thickness_m=th)
                            d = ((pred(params) - target) ** 2)[:, 0] - base
                            if float(d.mean()) <= SE_MARGIN * block_standard_error(d):
                                out[i] = min(out[i, 0], eps), max(out[i, 1], eps)
                            params.load_state_dict(keep)
            print(f"  eps_r range of material {i + 1}/{n} done", flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("rf", type=Path)
    ap.add_argument("measurements", type=Path)
    ap.add_argument("--eps-ranges", action="store_true", help="also scan the eps_r the links allow (minutes)")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    from rfir_core.artifacts import read_artifact
    from rfir_stages.model.room import RoomPredictor
    from rfir_stages.rf_fit.room_stage import material_rows

    rf = read_artifact(args.rf, "rf")
    meas = read_artifact(args.measurements, "measurements")
    pred = RoomPredictor(rf)
    room, f = pred.room, pred.freq_hz
    names = [str(s) for s in np.atleast_1d(rf.free["model@attrs"]["material_names"])]
    label_names = [str(s) for s in rf.attrs.get("label_names", [])]
    rows = np.asarray(rf.free["training"]["fit_rows"], np.int64)
    tx, rx = np.asarray(meas["tx_pos"])[rows], np.asarray(meas["rx_pos"])[rows]
    target = np.asarray(meas["path_gain_db"], np.float64)[rows, 0]
    with torch.no_grad():
        links = room.links(tx, rx, np.full(len(rows), f))
    per_mat, fewest = links_touching(room, links, label_names)
    fitted = material_rows(pred.mats, names, f)
    ranges = rf.get("material/gamma_normal_range")
    eps_r = eps_ranges(links, pred.mats, target, f) if args.eps_ranges else None
    truth = true_materials(str(rf.attrs.get("scene", "classroom")), names, f, measurement_scene_edits(meas))
    tabulated = [str(s) for s in np.atleast_1d(rf.free["model@attrs"].get("material_tabulated", [""] * len(names)))]
    out = []
    for i, (name, row) in enumerate(zip(names, fitted)):
        itu, th, eps, sig, g = truth[name]
        metal = itu == "metal"
        ok_g = abs(row["gamma_normal_abs"] - g) <= TARGET_GAMMA
        ok = (row["gamma_normal_abs"] >= METAL_GAMMA) if metal else (ok_g and abs(row["eps_r"] / eps - 1) <= TARGET_EPS)
        out.append({"material": name, "links": int(per_mat[i]), "fewest_links_one_object": int(fewest.get(name, 0)),
                    "fitted": {"gamma_normal_abs": row["gamma_normal_abs"], "eps_r": row["eps_r"],
                               "sigma_s_per_m": row["sigma_s_per_m"], "thickness_m": row["thickness_m"],
                               "scattering": row["scattering"]},
                    "taken_as_tabulated": tabulated[i],
                    "links_allow_gamma": None if ranges is None else [float(x) for x in np.asarray(ranges)[i]],
                    "links_allow_eps_r": None if eps_r is None or metal else [float(x) for x in eps_r[i]],
                    "simulator": {"material": itu, "thickness_m": th, "eps_r": eps, "sigma_s_per_m": sig,
                                  "gamma_normal_abs": g},
                    "gamma_within_0.1": bool(ok_g), "within_target": bool(ok)})
    print(f"{'material':<14} {'links':>5} {'min/obj':>7}  fitted |G0| eps_r  sigma     th mm  {'(tabulated)':<13} | "
          "simulator |G0| eps_r sigma th mm | |G0| allow  eps_r allow | target")
    for r in out:
        a, s = r["fitted"], r["simulator"]
        ga = "-" if r["links_allow_gamma"] is None else "{:.2f}-{:.2f}".format(*r["links_allow_gamma"])
        ea = "-" if r["links_allow_eps_r"] is None else "{:g}-{:g}".format(*r["links_allow_eps_r"])
        print(f"{r['material']:<14} {r['links']:>5} {r['fewest_links_one_object']:>7}  {a['gamma_normal_abs']:.2f} "
              f"{a['eps_r']:6.2f} {a['sigma_s_per_m']:8.3g} {a['thickness_m'] * 1e3:6.1f}  "
              f"{('(' + r['taken_as_tabulated'] + ')') if r['taken_as_tabulated'] else '':<13} | {s['material']:<8} "
              f"{s['gamma_normal_abs']:.2f} {s['eps_r']:5.2f} {s['sigma_s_per_m']:8.3g} {s['thickness_m'] * 1e3:5.1f} | "
              f"{ga:>9} {ea:>9} | {'yes' if r['within_target'] else 'no'} (|G0| {'yes' if r['gamma_within_0.1'] else 'no'})")
    if args.json:
        args.json.write_text(json.dumps({"rf": args.rf.name, "freq_hz": f, "fit_links": int(len(rows)),
                                         "materials": out}, indent=1) + "\n")


if __name__ == "__main__":
    main()
