"""`rfir predict rssi RF --tx X,Y,Z [--rx FILE | --grid H,STEP]`: radio maps from a fitted RSSI model."""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from ..context import RichReporter, comma_numbers, console, err_console, options, run_guarded
from rfir_core.text import plural
from .predict import predict_app


def register(app: typer.Typer) -> None:
    predict_app.command("rssi")(predict_rssi)


def predict_rssi(
    ctx: typer.Context,
    rf: Annotated[Path, typer.Argument(help="rf artifact from `rfir rf-fit` on task 'rssi' measurements.")],
    out: Annotated[Optional[Path], typer.Option("-o", "--out", help="predictions artifact (default: RF stem + _rssi.h5).")] = None,
    tx: Annotated[Optional[list[str]], typer.Option(
        "--tx", metavar="X,Y,Z", help="Transmitter position 'X,Y,Z' in metres; repeat it for several transmitters "
                                      "(a map each, the best server and, with --threshold-dbm, the coverage).")] = None,
    rx: Annotated[Optional[Path], typer.Option("--rx", metavar="CSV", help="CSV of receiver positions x,y,z in metres.")] = None,
    grid: Annotated[Optional[str], typer.Option("--grid", metavar="HEIGHT,STEP",
            help="'HEIGHT,STEP' in metres: receivers on a floor-plan grid.")] = None,
    measurements: Annotated[Optional[Path], typer.Option(
        "--measurements", help="RSSI measurements: without --tx, score every row on the model's test split.")] = None,
    plots: Annotated[Optional[Path], typer.Option("--plots", help="Folder for heatmap and FoV PNGs.")] = None,
    results: Annotated[Optional[Path], typer.Option(
        "--results", help="JSON with metrics (default: OUT with .json when scoring).")] = None,
    tx_power_dbm: Annotated[Optional[float], typer.Option(
        "--tx-power-dbm", metavar="DBM", help="Transmit power [dBm]: maps, map files and printed values in received "
                                              "power [dBm] instead of path gain [dB].")] = None,
    formats: Annotated[Optional[list[str]], typer.Option(
        "--format", metavar="csv|npz|tif", help="Map files beside OUT: csv (x,y,z,value), npz (arrays), tif (float32 "
                                                 "GeoTIFF of a --grid map); repeat it or give a comma list.")] = None,
    threshold_dbm: Annotated[Optional[float], typer.Option(
        "--threshold-dbm", metavar="DBM", help="Coverage: share of the points where the best transmitter gives at "
                                               "least this [dBm] (needs --tx-power-dbm).")] = None,
    freqs: Annotated[Optional[str], typer.Option(
        "--freqs", metavar="HZ", help="Frequencies [Hz] to predict at, '5.8e9' or '2.4e9,5.8e9', inside the range of "
                                      "the model's material laws (default: the one it was fitted at); the artifact "
                                      "holds a column each, the first is scored, mapped and plotted.")] = None,
) -> None:
    """Received power at points or on a grid for any transmitter; MAE beside baselines when measured."""
    opts = options(ctx)

    def work():
        from rfir_stages.predict.rssi import run_rssi

        out_path = out or rf.with_name(rf.stem + "_rssi.h5")
        results_path = results
        if results_path is None and measurements is not None and not tx:
            results_path = out_path.with_suffix(".json")
        txs = [comma_numbers(t, "--tx", 3) for t in tx] if tx else None
        freqs_hz = None if freqs is None else comma_numbers(freqs, "--freqs", len(freqs.split(",")))
        with RichReporter(opts.verbosity) as reporter:
            return run_rssi(rf, out_path, dict(opts.config().get("predict", {})), tx=txs,
                            rx_file=rx, grid=comma_numbers(grid, "--grid", 2), measurements_path=measurements,
                            plots_dir=plots, results_path=results_path, seed=opts.seed,
                            config_toml=opts.config_toml(), progress=reporter, tx_power_dbm=tx_power_dbm,
                            formats=formats or (), threshold_dbm=threshold_dbm, freqs_hz=freqs_hz)

    r = run_guarded(ctx, work)
    for w in r.warnings:
        err_console.print(f"[yellow]warning:[/yellow] {w}", highlight=False, soft_wrap=True)
    at = ", ".join(f"{f / 1e9:g}" for f in (r.freqs_hz or [r.freq_hz]))
    why = (" (the frequency the model was fitted at; --freqs predicts at others)" if r.freq_assumed else
           " (scored and mapped at the first)" if len(r.freqs_hz) > 1 else "")
    console.print(f"[green]wrote[/green] {r.path}: {plural(r.num_links, 'link')} at {at} GHz{why} "
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
    if r.num_tx:
        _map_lines(r)
    if r.plots:
        console.print(f"plots: {len(r.plots)} PNG in {Path(r.plots[0]).parent}", highlight=False)
    if r.results_json:
        console.print(f"results: {r.results_json}", highlight=False)


def _map_lines(r) -> None:
    """One line per transmitter's map (median and range over its points, points left out), then the best
    server's and the coverage's."""
    what = "received power" if r.unit == "dBm" else "path gain"
    power = f" (P_T = {r.metrics['tx_power_dbm']:g} dBm)" if r.unit == "dBm" else ""
    for i, (t, st) in enumerate(zip(r.tx_m, r.map_stats)):
        name = f"Tx {i + 1}" if r.num_tx > 1 else "Tx"
        left = f"; {st['left_out']} of {r.map_points} points left out" if st["left_out"] else ""
        console.print(f"{name} ({', '.join(f'{x:.2f}' for x in t)}) m: {what}{power} median {st['median']:.1f} "
                      f"{r.unit}, {st['min']:.1f} .. {st['max']:.1f} {r.unit} over {r.map_points} points{left}",
                      highlight=False)
    m = r.metrics
    if "best_tx_points" in m:
        shares = ", ".join(f"Tx {i + 1} {n}" for i, n in enumerate(m["best_tx_points"]))
        console.print(f"best server (points where each transmitter is the strongest): {shares}", highlight=False)
    if "coverage_share" in m:
        console.print(f"coverage: {100 * m['coverage_share']:.1f} % of {m['coverage_of_points']} points at or above "
                      f"{m['threshold_dbm']:g} dBm ({m['coverage_points']} points)", highlight=False)
    for f in r.map_files:
        console.print(f"[green]wrote[/green] {f}", highlight=False)
