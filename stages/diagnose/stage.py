"""`rfir diagnose MODEL measurements.h5 -o report/`: where the model and the data disagree, which
missing effect explains it, the effect added and refitted, the gap before and after (docs/guide/diagnose.md).

Steps: (1) where: breakdowns of the residual with held-out structure tests (breakdown.py);
(2)-(3) what and which: every candidate of the catalogue (effects.py) fitted on the training rows
and scored on the held-out rows (select.py); (4) the named effect is added to the model, all named
effects are refitted together, and the search repeats until no candidate is significant;
(5) report.md, results.json, effects.json and the plots; for an rf MODEL also model_with_effects.h5,
the rf artifact with the effects recorded (free group `effects`), which `rfir predict` applies.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rfir_core.errors import ConfigError
from rfir_core.progress import NullProgress
from rfir_core.text import plural

from .breakdown import AXIS, LARGE_R2, analyse, plot
from .data import load_rows
from .effects import CATALOGUE
from .select import chain_to_json, compose, search


@dataclass
class DiagnoseResult:
    out_dir: Path
    steps: list = field(default_factory=list)     # one dict per step (gap before/after, named effect)
    named: list = field(default_factory=list)     # [{"effect", "params", "confidence"}]
    ambiguous: list = field(default_factory=list)  # significant but no clear winner: the candidates
    mae_before_db: float = float("nan")
    mae_after_db: float = float("nan")
    files: list = field(default_factory=list)
    headline: str = ""
    wall_s: float = 0.0
    frequencies: str = ""                          # the frequencies predicted and why, in words (data.load_rows)


def _mae(rows, pred, mask) -> float:
    return float(np.mean(np.abs(rows.meas_db[mask] - pred[mask])))


def run(model_path, measurements_path, out_dir, *, geometry_path=None, max_effects: int = 4, seed: int = 0,
        config_toml: str = "", progress=None) -> DiagnoseResult:
    """Diagnose MODEL against the measurements into out_dir (module docstring)."""
    progress = progress or NullProgress()
    t0 = time.time()
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise ConfigError(f"-o {out}: exists and is not a folder")
    for p in (model_path, measurements_path):
        if Path(p).resolve() == out.resolve():
            raise ConfigError(f"-o {out}: would overwrite an input")
    out.mkdir(parents=True, exist_ok=True)
    rows, info = load_rows(model_path, measurements_path, out, geometry_path=geometry_path, seed=seed,
                           progress=progress)
    res = DiagnoseResult(out, frequencies=info.get("frequencies", ""))
    current = rows.pred_db.copy()
    where0 = analyse(rows, current, seed)
    res.files.append(plot(out / "residual_before.png", rows, rows.meas_db - current, where0,
                          f"residual measured - predicted, before: held-out MAE {_mae(rows, current, rows.test):.2f} dB"))
    res.mae_before_db = _mae(rows, current, rows.test)
    ratio = _complex_ratio(rows)
    with progress.task("diagnose", total=max_effects) as bar:
        chain, res.steps, res.named, res.ambiguous = search(rows, max_effects, seed, advance=bar.advance)
    current = compose(chain, rows)
    res.mae_after_db = _mae(rows, current, rows.test)
    where1 = analyse(rows, current, seed)
    if chain:
        res.files.append(plot(out / "residual_after.png", rows, rows.meas_db - current, where1,
                              f"residual after adding {', '.join(n['effect'] for n in res.named)}: "
                              f"held-out MAE {res.mae_after_db:.2f} dB",
                              boxes=[x[1:5] for e, x in chain if e.name == "obstacle"]))
    lacking = lacking_structure(where1, "residual_after.png" if chain else "residual_before.png")
    res.headline = headline(res.named, res.ambiguous, lacking)
    untested = [e.name for e in CATALOGUE if e.needs_phase] if info["phases"] != "measured" else []
    effects_json = chain_to_json(chain)
    (out / "effects.json").write_text(json.dumps(effects_json, indent=2) + "\n")
    res.files.append(out / "effects.json")
    if info["model_kind"] == "rf" and chain:
        res.files.append(_write_model(Path(model_path), out / "model_with_effects.h5", effects_json, config_toml))
    res.wall_s = time.time() - t0
    results = {"info": info, "mae_before_db": res.mae_before_db, "mae_after_db": res.mae_after_db,
               "gap_shrink": 1 - res.mae_after_db / res.mae_before_db if res.mae_before_db > 0 else 0.0,
               "headline": res.headline, "lacking": lacking, "phases": info["phases"],
               "untested_without_phase": untested, "named": res.named, "ambiguous": res.ambiguous,
               "steps": res.steps, "complex_ratio": ratio,
               "where_before": [_where_json(b) for b in where0], "where_after": [_where_json(b) for b in where1],
               "wall_s": res.wall_s}
    (out / "results.json").write_text(json.dumps(results, indent=2, default=float) + "\n")
    (out / "report.md").write_text(_report_md(results))
    res.files += [out / "results.json", out / "report.md"]
    return res


def lacking_structure(where_after, plot_name: str) -> list[dict]:
    """Breakdowns that still have structure after the named effects, strongest first: [{axis, feature,
    r2_heldout, p_value, large (R^2 > LARGE_R2), plot}]."""
    found = sorted([b for b in where_after if b.structure], key=lambda b: -b.r2_heldout)
    return [{"axis": AXIS.get(b.feature, b.feature), "feature": b.feature, "r2_heldout": b.r2_heldout,
             "p_value": b.p_value, "large": bool(b.r2_heldout > LARGE_R2), "worst_bin": b.worst_bin,
             "plot": plot_name} for b in found]


def headline(named: list, ambiguous: list, lacking: list[dict]) -> str:
    """The report's first line: structure the model lacks leads when a breakdown still explains a large
    share of the residual; "no missing effect" only when no breakdown finds structure."""
    said = f"named {' + '.join(n['effect'] for n in named)}" if named else ""
    if ambiguous and not named:
        said = f"ambiguous: {' / '.join(ambiguous)} explain the residual about equally; none added"
    if lacking and lacking[0]["large"]:
        axes = ", ".join(f"{w['axis']} (held-out R2 {w['r2_heldout']:.2f}, worst {w['worst_bin']})"
                         for w in lacking if w["large"])
        text = f"structure the model lacks, not in the catalogue: by {axes}; see {lacking[0]['plot']}"
        return f"{text}; {said}" if said else text
    if said:
        return said
    if lacking:
        top = lacking[0]
        return (f"no catalogue effect reproduces the residual; weak structure by {top['axis']} (held-out R2 "
                f"{top['r2_heldout']:.2f}); see {top['plot']}")
    return "no missing effect: no breakdown of the residual has structure"


def _complex_ratio(rows) -> dict | None:
    """Measured / predicted complex channel where both give phase: magnitude [dB] and phase [deg]
    (median, and the circular spread of the phase), per aspect bin of 10 deg for turntable data."""
    if rows.meas_channel is None or rows.pred_channel is None:
        return None
    ok = np.abs(rows.pred_channel) > 0
    ratio = rows.meas_channel[ok] / rows.pred_channel[ok]
    phase = np.angle(ratio)
    out = {"median_magnitude_db": float(np.median(20 * np.log10(np.maximum(np.abs(ratio), 1e-30)))),
           "median_phase_deg": float(np.degrees(np.angle(np.mean(np.exp(1j * phase))))),
           "phase_spread_deg": float(np.degrees(np.sqrt(-2 * np.log(max(abs(np.mean(np.exp(1j * phase))), 1e-12)))))}
    if rows.aspect_rad is not None:
        b = (np.degrees(np.mod(rows.aspect_rad[ok], 2 * np.pi)) // 10).astype(int)
        out["phase_deg_per_10deg_aspect"] = [float(np.degrees(np.angle(np.mean(np.exp(1j * phase[b == i])))))
                                            if np.any(b == i) else None for i in range(36)]
    return out


def _where_json(b) -> dict:
    return {"feature": b.feature, "r2_heldout": b.r2_heldout, "p_value": b.p_value, "structure": b.structure,
            "worst_bin": b.worst_bin, "worst_mae_db": b.worst_mae_db}


def _write_model(rf_path: Path, out_path: Path, effects_json: list, config_toml: str) -> Path:
    """The rf artifact with the effects chain in free group `effects` (predict applies it)."""
    from rfir_core.artifacts import read_artifact, write_artifact
    from rfir_core.provenance import Provenance

    rf = read_artifact(rf_path, "rf")
    free = rf.free_for_write()
    free["effects"] = {"@attrs": {"chain_json": json.dumps(effects_json),
                                  "doc": "stages/diagnose/effects.py; applied in order to predicted path gain"}}
    prov = Provenance(stage="diagnose", config_toml=config_toml)
    prov.add_input(rf_path)
    prov.extra = {"upstream": rf.provenance.stage, "effects": effects_json}
    write_artifact(out_path, "rf", dict(rf.data), attrs=dict(rf.attrs), provenance=prov, free=free)
    return out_path


def _report_md(r: dict) -> str:
    info = r["info"]
    lines = [f"# Diagnosis of {info['model']}", "", f"**{r['headline']}**", "",
             f"Measurements: `{info['measurements']}` ({info['task']}, {plural(info['num_links'], 'link')} x "
             f"{plural(info['num_freqs'], 'frequency')}; {info['num_train']} train / {info['num_test']} held-out rows, {info['split']}).", "",
             f"Predicted at {info.get('frequencies', 'the measured frequencies')}.", "",
             "## Gap", "", "| step | named effect | confidence | held-out MAE before | after | parameters |",
             "|---|---|---|---|---|---|"]
    for s in r["steps"]:
        if s["named"] is None and s.get("ambiguous"):
            lines.append(f"| {s['step']} | ambiguous: {' / '.join(s['ambiguous'])} (best {s['confidence']:.0%}) | | "
                         f"{s['test_mae_before_db']:.2f} dB | | |")
        elif s["named"] is None:
            lines.append(f"| {s['step']} | no further significant catalogue effect | | {s['test_mae_before_db']:.2f} dB | | |")
        else:
            params = ", ".join(f"{k} = {v:.4g}" for k, v in s["params"].items())
            lines.append(f"| {s['step']} | **{s['named']}** | {s['confidence']:.0%} | {s['test_mae_before_db']:.2f} dB | "
                         f"{s['test_mae_after_db']:.2f} dB | {params} |")
    lines += ["", f"Held-out MAE {r['mae_before_db']:.2f} -> {r['mae_after_db']:.2f} dB "
              f"(gap shrunk by {100 * r['gap_shrink']:.0f} %).", "", f"Phases: {r['phases']}."]
    if r["untested_without_phase"]:
        lines[-1] += f" Not tested without measured phases: {', '.join(r['untested_without_phase'])}."
    if r["lacking"]:
        lines += ["", "Structure left after the named effects (no catalogue effect reproduces it):", ""]
        lines += [f"- by {w['axis']}: held-out R2 {w['r2_heldout']:.2f} (p {w['p_value']:.3f}), worst {w['worst_bin']}"
                  for w in r["lacking"]]
    lines += ["", "## Where (before)", "",
              "| breakdown | held-out R2 | permutation p | structure | worst bin (MAE) |", "|---|---|---|---|---|"]
    for w in r["where_before"]:
        lines.append(f"| {w['feature']} | {w['r2_heldout']:.3f} | {w['p_value']:.3f} | {'yes' if w['structure'] else 'no'} "
                     f"| {w['worst_bin']} ({w['worst_mae_db']:.2f} dB) |")
    if r.get("complex_ratio"):
        c = r["complex_ratio"]
        lines += ["", f"Complex ratio measured / predicted (both give phase): median {c['median_magnitude_db']:.2f} dB, "
                  f"phase {c['median_phase_deg']:.1f} deg (circular spread {c['phase_spread_deg']:.1f} deg)."]
    lines += ["", "![before](residual_before.png)", ""]
    if r["named"]:
        lines += ["![after](residual_after.png)", ""]
    lines += ["## Candidates at step 1", "", "Score: held-out information criterion 2 n ln(MAE before / after) - 2 k "
              "(k fitted parameters).", "",
              "| effect | applies | held-out MAE before -> after | gain | t | k | score | significant | parameters |",
              "|---|---|---|---|---|---|---|---|---|"]
    for c in r["steps"][0]["candidates"]:
        if not c["applies"]:
            lines.append(f"| {c['effect']} | no: {c['reason']} | | | | |")
        else:
            items = list(c["params"].items())
            params = ", ".join(f"{k} = {v:.4g}" for k, v in items[:6]) + (", ..." if len(items) > 6 else "")
            lines.append(f"| {c['effect']} | yes | {c['test_mae_before_db']:.2f} -> {c['test_mae_db']:.2f} dB | "
                         f"{c['gain_db']:.3f} dB | {c['t_stat']:.1f} | {c['num_params']} | {c['score']:.1f} | "
                         f"{'yes' if c['significant'] else 'no'}{' (' + c['note'] + ')' if c['note'] else ''} | {params} |")
    return "\n".join(lines) + "\n"
