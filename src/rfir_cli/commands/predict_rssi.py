"""`rfir predict rssi RF --tx X,Y,Z [--rx FILE | --grid H,STEP]`: radio maps from a fitted RSSI model."""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from ..context import RichReporter, comma_numbers, console, err_console, options, run_guarded
from ..text import plural
from .predict import predict_app


def register(app: typer.Typer) -> None:
    predict_app.command("rssi")(predict_rssi)


def predict_rssi(
    ctx: typer.Context,
    rf: Annotated[Path, typer.Argument(help="rf artifact from `rfir rf-fit` on task 'rssi' measurements.")],
    out: Annotated[Optional[Path], typer.Option("-o", "--out", help="predictions artifact (default: RF stem + _rssi.h5).")] = None,
    tx: Annotated[Optional[str], typer.Option("--tx", metavar="X,Y,Z", help="Transmitter position 'X,Y,Z' in metres.")] = None,
    rx: Annotated[Optional[Path], typer.Option("--rx", metavar="CSV", help="CSV of receiver positions x,y,z in metres.")] = None,
    grid: Annotated[Optional[str], typer.Option("--grid", metavar="HEIGHT,STEP",
            help="'HEIGHT,STEP' in metres: receivers on a floor-plan grid.")] = None,
    measurements: Annotated[Optional[Path], typer.Option(
        "--measurements", help="RSSI measurements: without --tx, score every row on the model's test split.")] = None,
    plots: Annotated[Optional[Path], typer.Option("--plots", help="Folder for heatmap and FoV PNGs.")] = None,
    results: Annotated[Optional[Path], typer.Option(
        "--results", help="JSON with metrics (default: OUT with .json when scoring).")] = None,
) -> None:
    """Received power at points or on a grid for any transmitter; MAE beside baselines when measured."""
    opts = options(ctx)

    def work():
        from rfir_stages.predict.rssi import run_rssi

        out_path = out or rf.with_name(rf.stem + "_rssi.h5")
        results_path = results
        if results_path is None and measurements is not None and tx is None:
            results_path = out_path.with_suffix(".json")
        with RichReporter(opts.verbosity) as reporter:
            return run_rssi(rf, out_path, dict(opts.config().get("predict", {})), tx=comma_numbers(tx, "--tx", 3),
                            rx_file=rx, grid=comma_numbers(grid, "--grid", 2), measurements_path=measurements,
                            plots_dir=plots, results_path=results_path, seed=opts.seed,
                            config_toml=opts.config_toml(), progress=reporter)

    r = run_guarded(ctx, work)
    for w in r.warnings:
        err_console.print(f"[yellow]warning:[/yellow] {w}", highlight=False, soft_wrap=True)
    console.print(f"[green]wrote[/green] {r.path}: {plural(r.num_links, 'link')} at {r.freq_hz / 1e9:g} GHz "
                  f"({r.predict_time_s:.2f} s predicting, {r.wall_time_s:.2f} s in all)", highlight=False)
    m = r.metrics
    if "mae_db" in m:
        table = Table("method", f"MAE on the test split, dB (n = {m['num_test']})", box=None, pad_edge=False)
        table.add_row("rfir (this model)", f"{m['mae_db']:.2f}")
        table.add_row("baseline: log-distance (fitted)", f"{m['baseline_log_distance_mae_db']:.2f}")
        table.add_row("baseline: multi-wall (fitted)", f"{m['baseline_multiwall_mae_db']:.2f}")
        table.add_row("baseline: mean of the 4 nearest training links", f"{m['baseline_nearest_links_mae_db']:.2f}")
        console.print(table)
        console.print(f"split: {m['split']}; train MAE {m['mae_train_db']:.2f} dB", highlight=False)
    elif "mae_db_this_tx" in m:
        console.print(f"MAE against the measurements of this transmitter: {m['mae_db_this_tx']:.2f} dB "
                      f"({m['num_points']} points)", highlight=False)
    if r.plots:
        console.print(f"plots: {len(r.plots)} PNG in {Path(r.plots[0]).parent}", highlight=False)
    if r.results_json:
        console.print(f"results: {r.results_json}", highlight=False)
