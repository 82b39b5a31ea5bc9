"""`rfir edit RF -o OUT --select S --op O [...]`: move, rotate, delete, duplicate or re-material Gaussians.

Selections and operations are strings (docs/guide/edit.md): `--select sphere:0,0,0,0.2 --op translate:1,0,0`;
repeat the pair for several edits, or give a TOML edit script with --script.
"""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from ..context import RichReporter, comma_numbers, console, err_console, options, run_guarded


def register(app: typer.Typer) -> None:
    app.command("edit")(edit)


def edit(
    ctx: typer.Context,
    rf: Annotated[Path, typer.Argument(help="rf artifact to edit (from `rfir rf-fit`).")],
    out: Annotated[Optional[Path], typer.Option("-o", "--out", metavar="FILE",
            help="Edited rf artifact to write (.h5); not the input.")] = None,
    select: Annotated[Optional[list[str]], typer.Option(
        "--select", metavar="SELECTION", help="box:XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX | obox:CX,CY,CZ,HX,HY,HZ[,YAW,PITCH,ROLL] | "
                         "sphere:CX,CY,CZ,R | label:NAME | all (repeatable, paired with --op in order).")] = None,
    op: Annotated[Optional[list[str]], typer.Option(
        "--op", metavar="OP", help="translate:DX,DY,DZ | rotate:AX,AY,AZ,DEG[,PX,PY,PZ] | delete | duplicate:DX,DY,DZ | "
                     "material:NAME (an ITU-R P.2040 material, e.g. metal) | label:NAME (repeatable).")] = None,
    script: Annotated[Optional[Path], typer.Option(
        "--script", metavar="FILE", help="TOML edit script: a list of edit tables with select and op keys (docs/guide/edit.md).")] = None,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="List what each edit selects; write nothing.")] = False,
    allow_empty: Annotated[bool, typer.Option("--allow-empty", help="Skip edits whose selection is empty.")] = False,
    plot: Annotated[Optional[Path], typer.Option(
        "--plot", metavar="FILE", help="Before/after top-view PNG of the Gaussians, and PLOT_radio.png: the radio change.")] = None,
    map_tx: Annotated[Optional[str], typer.Option(
        "--map-tx", metavar="X,Y,Z",
                help="X,Y,Z (m): the transmitter of the radio-map change of an RSSI model (with --plot).")] = None,
    freq: Annotated[Optional[float], typer.Option(
        "--freq", metavar="HZ", help="Frequency [Hz] of the radio change (with --plot), e.g. 5.8e9; an RSSI model "
                                     "predicts inside its material laws' range. Default: the fitted frequency.")] = None,
) -> None:
    """Edit the Gaussians of an rf artifact; predict the edited scene with `rfir predict` (no new measurements)."""
    opts = options(ctx)

    def work():
        from rfir_stages.edit import run
        from rfir_stages.edit.script import edits_from_options, read_script

        edits = edits_from_options(list(select or []), list(op or []), allow_empty)
        if script is not None:
            edits += read_script(script, allow_empty)
        with RichReporter(opts.verbosity) as reporter:
            return run(rf, out, edits, dry_run=dry_run, allow_empty=allow_empty, plot_path=plot,
                       map_tx=comma_numbers(map_tx, "--map-tx", 3), freq_hz=freq, config_toml=opts.config_toml(), progress=reporter)

    r = run_guarded(ctx, work)
    for i, rec in enumerate(r.records, 1):
        what = rec["op"] or "(list only)"
        console.print(f"edit {i}: {rec['select']} selects {rec['selected']} Gaussians -> {what}", highlight=False)
    for w in r.warnings:
        err_console.print(f"[yellow]warning:[/yellow] {w}", highlight=False, soft_wrap=True)
    if r.path is not None:
        console.print(f"[green]wrote[/green] {r.path}: {r.num_before} -> {r.num_after} Gaussians", highlight=False)
    else:
        console.print(f"dry run: {r.num_before} -> {r.num_after} Gaussians, nothing written", highlight=False)
    if r.plot is not None:
        console.print(f"plot: {r.plot}", highlight=False)
    if r.radio_plot is not None:
        why = " (the frequency the model was fitted at; --freq sets another)" if r.radio_freq_assumed else ""
        console.print(f"radio change: {r.radio_plot} at {r.radio_freq_hz / 1e9:g} GHz{why} (mean |change| "
                      f"{r.radio_change['mean_abs_change_db']:.2f} dB, max {r.radio_change['max_abs_change_db']:.2f} dB "
                      f"over {r.radio_change['points']} points)", highlight=False)

