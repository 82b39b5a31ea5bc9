"""The RCS physical model's fitted materials against the simulator's, at every fitted frequency.

    python scripts/rcs_material_table.py RF.h5 [--json OUT.json]

RF.h5 is an rf artifact of `rfir rf-fit` on RCS data of an object scene `rfir simulate` builds (lego,
trio, car, ...; the scene name is read from the artifact). For each fitted material (one per object
class) and each fitted frequency: the fitted |Gamma(0)| (material/gamma_normal_abs) and the range the
training links allow (material/gamma_normal_range, first frequency), the simulator's |Gamma(0)| of
its ITU-R P.2040 material and slab thickness (rfir_stages.simulate.truth), and whether issue 22's
target holds: |Gamma(0)| within 0.1 at every fitted frequency, a metal fitted as a metal
(|Gamma(0)| > 0.9). A report, not a stage: exit 2 with one line when the artifact is not such a fit.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from rfir_stages.simulate.truth import true_materials

TARGET_GAMMA = 0.1
METAL_GAMMA = 0.9


def _truth(scene: str, names: list[str], freq_hz: float) -> dict:
    """true_materials, with the name "scene" (one material for the scene: rf_fit.physical.sharing =
    global) standing for the scene's material when all its objects share one."""
    from rfir_stages.simulate import build_scene
    from rfir_stages.simulate.truth import object_class

    classes = sorted({object_class(o.name) for o in build_scene(scene).objects})
    out = true_materials(scene, classes, freq_hz)
    if "scene" in names and "scene" not in out and len({v[:2] for v in out.values()}) == 1:
        out["scene"] = next(iter(out.values()))
    return out


def material_table(rf) -> dict:
    """Rows of fitted vs true |Gamma(0)| per material and frequency for an rf artifact (see module doc)."""
    attrs = rf.free["model@attrs"]
    names = [str(s) for s in np.atleast_1d(attrs["material_names"])]
    freqs = np.atleast_1d(np.asarray(rf.get("rf/freq_hz"), np.float64))
    fitted = np.asarray(rf.get("material/gamma_normal_abs"), np.float64).reshape(len(names), len(freqs))
    ranges = rf.get("material/gamma_normal_range")
    scene = str(rf.attrs.get("scene", ""))
    truth = {f: _truth(scene, names, float(f)) for f in freqs}
    rows = []
    for i, name in enumerate(names):
        if name not in truth[freqs[0]]:
            raise ValueError(f"material {name!r} is no object class of the simulator's scene {scene!r} "
                             "(a scene-wide material of a scene with several materials has no single truth)")
        itu, th = truth[freqs[0]][name][:2]
        true_g = [truth[f][name][4] for f in freqs]
        within = [abs(a - b) <= TARGET_GAMMA for a, b in zip(fitted[i], true_g)]
        metal = itu == "metal"
        ok = bool(all(fitted[i] > METAL_GAMMA)) if metal else all(within)
        rows.append({"material": name, "simulator": {"material": itu, "thickness_m": th, "gamma_normal_abs": true_g},
                     "fitted_gamma_normal_abs": [float(x) for x in fitted[i]],
                     "links_allow": None if ranges is None else [float(x) for x in np.asarray(ranges)[i]],
                     "gamma_within_0.1": [bool(w) for w in within], "within_target": bool(ok)})
    return {"scene": scene, "freq_hz": [float(f) for f in freqs], "materials": rows}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rf", type=Path)
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    from rfir_core.artifacts import read_artifact
    from rfir_core.errors import RfirError

    try:
        rf = read_artifact(args.rf, "rf")
        if rf.get("material/gamma_normal_abs") is None:
            raise ValueError("no fitted materials (material/gamma_normal_abs): not a physical-model fit")
        table = material_table(rf)
    except (RfirError, OSError, ValueError, KeyError) as exc:
        print(f"error: {exc}" if isinstance(exc, RfirError) else f"error: {args.rf}: {exc}", file=sys.stderr)
        sys.exit(2)
    ghz = " / ".join(f"{f / 1e9:g}" for f in table["freq_hz"])
    print(f"{table['scene']}: |Gamma(0)| at {ghz} GHz, fitted against the simulator's")
    print(f"{'material':<12} {'simulator':<20} {'true':<14} {'fitted':<14} {'links allow':<12} target")
    for r in table["materials"]:
        s = r["simulator"]
        sim = f"{s['material']} {s['thickness_m'] * 1e3:g} mm"
        true = " / ".join(f"{g:.2f}" for g in s["gamma_normal_abs"])
        fit = " / ".join(f"{g:.2f}" for g in r["fitted_gamma_normal_abs"])
        allow = "-" if r["links_allow"] is None else "{:.2f}-{:.2f}".format(*r["links_allow"][:2])
        print(f"{r['material']:<12} {sim:<20} {true:<14} {fit:<14} {allow:<12} {'yes' if r['within_target'] else 'no'}")
    if args.json:
        args.json.write_text(json.dumps(table, indent=1) + "\n")


if __name__ == "__main__":
    main()
