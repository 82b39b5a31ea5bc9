"""Run `rfir diagnose` on every hidden-effect data set of scripts/diagnose_hidden.sh and print the table
of named effect versus truth (issue 10). usage: python scripts/diagnose_table.py DATA_DIR [RESULTS_JSON]"""
import json
import sys
import time
from pathlib import Path

from rfir_stages.diagnose import run

CASES = [  # (model, measurements, truth); the first block is the quick (physical-optics) set
    ("lego_po_clean", "lego_po_gain", "gain_offset"),
    ("lego_po_clean", "lego_po_turntable", "turntable_offset"),
    ("lego_po_clean", "lego_po_leakage", "leakage"),
    ("htarget_clean", "htarget_ripple", "ripple"),
    ("lego_po_clean", "lego_po_noisy", None),
    ("room_clean", "room_gain", "gain_offset"),
    ("room_clean", "room_noise_floor", "noise_floor"),
    ("room_clean", "room_saturation", "saturation"),
    ("room_out_no_transmission", "room_out_clean", "wall_transmission"),
    ("room_specular_only", "room_clean", "diffuse_lobe"),
    ("room_depth1", "room_clean", "double_bounce"),
    ("lego_clean", "lego_turntable", "turntable_offset"),
    ("lego_clean", "lego_leakage", "leakage"),
    ("lego_specular_only", "lego_clean", "diffuse_lobe"),
    ("lego_clean", "lego_gain", "gain_offset"),
    ("room_clean", "room_other_seed", None),
    ("room_clean", "room_noisy", None),
    ("lego_clean", "lego_other_seed", None),
    ("lego_clean", "lego_noisy", None),
]


def main():
    data = Path(sys.argv[1])
    rows = []
    print("| model | measurements | truth | named (confidence) | parameters | held-out MAE before -> after | shrink | time |")
    print("|---|---|---|---|---|---|---|---|")
    for model, meas, truth in CASES:
        if not (data / model / "measurements.h5").exists() or not (data / meas / "measurements.h5").exists():
            continue
        t0 = time.time()
        geometry = data / "room_geometry.h5" if model.startswith("room") else None
        res = run(data / model / "measurements.h5", data / meas / "measurements.h5", data / f"report_{model}_{meas}",
                  geometry_path=geometry)
        named = [n["effect"] for n in res.named]
        first = res.named[0] if res.named else None
        params = ", ".join(f"{k} = {v:.3g}" for k, v in first["params"].items()) if first else ""
        shrink = 1 - res.mae_after_db / res.mae_before_db if res.mae_before_db > 0 else 0.0
        ok = (named[:1] == [truth]) if truth else not named
        rows.append({"model": model, "measurements": meas, "truth": truth, "named": named, "params": params,
                     "mae_before_db": res.mae_before_db, "mae_after_db": res.mae_after_db, "shrink": shrink,
                     "correct": ok, "wall_s": time.time() - t0})
        label = ", ".join(f"{n['effect']} ({n['confidence']:.0%})" for n in res.named) or "none"
        print(f"| {model} | {meas} | {truth or 'none'} | {'OK ' if ok else 'WRONG '}{label} | {params} | "
              f"{res.mae_before_db:.2f} -> {res.mae_after_db:.2f} dB | {100 * shrink:.0f} % | {time.time() - t0:.0f} s |",
              flush=True)
    if len(sys.argv) > 2:
        Path(sys.argv[2]).write_text(json.dumps(rows, indent=2) + "\n")


if __name__ == "__main__":
    main()
