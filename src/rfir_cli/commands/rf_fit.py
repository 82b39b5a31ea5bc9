"""`rfir rf-fit SCENE MEASUREMENTS -o RF`: the physical radio model's materials fitted to measurements."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Annotated, Optional

import typer

from ..context import RichReporter, console, options, run_guarded
from rfir_core.text import plural


def register(app: typer.Typer) -> None:
    app.command("rf-fit")(rf_fit)


def rf_fit(
    ctx: typer.Context,
    scene: Annotated[Path, typer.Argument(help="Scene artifact (Gaussians + normals), or an rf artifact to refit.")],
    measurements: Annotated[Path, typer.Argument(help="Measurements artifact; the training rows of --split are fitted.")],
    out: Annotated[Path, typer.Option("-o", "--out", metavar="FILE", help="rf artifact to write (.h5).")],
    iterations: Annotated[Optional[int], typer.Option(
        "--iterations", metavar="N",
        help="Adam steps of the material fit from its best start (rf_fit.physical.iterations). Every starting "
             "material and each round of switching starts runs rf_fit.physical.start_iterations steps before them, "
             "so the fit runs more steps in all; the total is printed at the end.")] = None,
    freq_hz: Annotated[Optional[list[float]], typer.Option(
        "--freq", "--freq-hz", metavar="HZ",
        help="Fit only these frequencies in Hz (repeatable; default: all in the file).")] = None,
    range_m: Annotated[Optional[str], typer.Option(
        "--range", metavar="METRES", help="Fit only rows at these ranges in metres: '3' or '2,3' (default: all).")] = None,
    aspects: Annotated[Optional[str], typer.Option(
        "--aspects", metavar="DEGREES", help="Fit only rows at these aspects in degrees: '0:90' ([0, 90)), '315:45', '45', "
                          "comma-joined (default: all).")] = None,
    checkpoint: Annotated[Optional[Path], typer.Option(
        "--checkpoint", metavar="FILE", help="Checkpoint file; the model selection is recorded in CHECKPOINT.selection "
                             "(default: OUT.ckpt.pt).")] = None,
    resume: Annotated[bool, typer.Option("--resume", help="Reuse the recorded model selection of the same run.")] = False,
    split: Annotated[Optional[str], typer.Option(
        "--split", metavar="PROTOCOL",
                help="Train/test protocol of RCS data (rf_fit.split): data, every-N, sector:A:B (deg), range:R (m). "
                     "RSSI data use the file's split column (rfir import csv --split random:0.2|holdout-tx:N|"
                     "block:SIZE) or rf_fit.rssi.split.")] = None,
) -> None:
    """Fit the materials (eps_r, sigma, thickness, scattering S) of the physical model (geometry frozen)."""
    t_start = time.time()   # the recorded wall time covers the whole command
    opts = options(ctx)

    def work():
        from rfir_stages.importers.select import parse_selection
        from rfir_stages.rf_fit import run

        select = parse_selection(None, range_m, aspects)
        table = dict(opts.config().get("rf_fit", {}))
        if iterations is not None:
            table["physical"] = dict(table.get("physical") or {}, iterations=int(iterations))
        if split is not None:
            table["split"] = split
        if freq_hz:
            table["freqs_hz"] = [float(f) for f in freq_hz]
        with RichReporter(opts.verbosity) as reporter:
            return run(scene, measurements, out, table, seed=opts.seed, config_toml=opts.config_toml(),
                       progress=reporter, checkpoint=checkpoint, resume=resume, select=select,
                       t_start=t_start, device=opts.torch_device())

    r = run_guarded(ctx, work)
    from rfir_stages.rf_fit.stage import sharing_words

    console.print(f"[green]wrote[/green] {r.path}: {r.num_gaussians} Gaussians, {plural(r.num_train_links, 'training link')} "
                  f"x {len(r.freqs_hz)} freq; train MAE {r.initial_mae_db:.2f} -> {r.train_mae_db:.2f} dB in "
                  f"{plural(r.iterations, 'Adam step')} ({_timing_text(r.wall_time_s, r.timings_s)}, {r.occlusion})"
                  + (f"; {sharing_words(r.selection['sharing_selected'])}" if r.selection else ""),
                  highlight=False)
    for w in r.warnings:
        console.print(f"[yellow]warning:[/yellow] {w}", highlight=False)


def _timing_text(wall_s: float, parts: dict) -> str:
    """'312 s in all: trace 12 s, model selection 240 s, fit 58 s' (the parts a fit recorded)."""
    names = (("trace", "trace"), ("select", "model selection"), ("fit", "fit"))
    sec = lambda t: f"{t:.0f} s" if t >= 10 else f"{t:.1f} s"  # noqa: E731
    shown = [f"{text} {sec(parts[k])}" for k, text in names if parts.get(k, 0) >= 0.05]
    return f"{sec(wall_s)} in all" + (": " + ", ".join(shown) if shown else "")
