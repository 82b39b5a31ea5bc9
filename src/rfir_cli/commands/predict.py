"""`rfir predict rcs RF -o PRED`: RCS predicted by a fitted rf artifact (plots, MAE table, results JSON)."""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from ..context import RichReporter, console, options, run_guarded
from rfir_core.errors import ConfigError
from rfir_core.text import plural

predict_app = typer.Typer(help="Predict radio quantities from a fitted rf artifact.", no_args_is_help=True,
                         rich_markup_mode=None)


def register(app: typer.Typer) -> None:
    app.add_typer(predict_app, name="predict")


def _parse_list(text: Optional[str], what: str) -> Optional[list[float]]:
    """'0:360:2' (start:stop:step, stop excluded) or '2,2.5,3' -> floats."""
    if text is None:
        return None
    try:
        if ":" in text:
            import numpy as np

            start, stop, step = (float(x) for x in text.split(":"))
            return [float(v) for v in np.arange(start, stop - 1e-9, step)]
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ConfigError(f"{what} {text!r}: expected a comma list or start:stop:step") from None


@predict_app.command("rcs")
def predict_rcs(
    ctx: typer.Context,
    rf: Annotated[Path, typer.Argument(help="rf artifact from `rfir rf-fit`.")],
    out: Annotated[Path, typer.Option("-o", "--out", metavar="FILE", help="predictions artifact to write (.h5).")],
    measurements: Annotated[Optional[Path], typer.Option(
        "--measurements", metavar="FILE", help="Measurements to predict and compare with (their rows and split).")] = None,
    aspects: Annotated[Optional[str], typer.Option(
        "--aspects", metavar="DEGREES", help="Degrees: '0:360:1' or '0,90,180'; with --measurements also '0:90' ([0, 90) of the "
                          "measured rows).")] = None,
    ranges: Annotated[Optional[str], typer.Option("--range", "--ranges", metavar="METRES", help="Metres: '3' or '2,3,5'.")] = None,
    freqs: Annotated[Optional[str], typer.Option(
        "--freq", "--freqs", metavar="HZ", help="Hz: '2.4e9' (fitted ones; any inside the band of a wideband model).")] = None,
    plots: Annotated[Optional[Path], typer.Option("--plots", metavar="DIR", help="Folder for PNG plots.")] = None,
    results: Annotated[Optional[Path], typer.Option(
        "--results", metavar="FILE", help="JSON with metrics (default: OUT with .json when --measurements).")] = None,
) -> None:
    """Predict monostatic RCS versus aspect, range and frequency; compare on the test split when measured."""
    opts = options(ctx)

    def work():
        from rfir_stages.importers.select import parse_selection
        from rfir_stages.predict import run_rcs

        results_path = results
        if results_path is None and measurements is not None:
            results_path = out.with_suffix(".json")
        with RichReporter(opts.verbosity) as reporter:
            measured = measurements is not None   # measured rows are selected (intervals allowed), else made
            return run_rcs(rf, out, dict(opts.config().get("predict", {})), measurements_path=measurements,
                           aspects_deg=None if measured else _parse_list(aspects, "--aspects"),
                           ranges_m=None if measured else _parse_list(ranges, "--range"),
                           select=parse_selection(None, ranges, aspects) if measured else None,
                           freqs_hz=_parse_list(freqs, "--freqs"), plots_dir=plots, results_path=results_path,
                           seed=opts.seed, config_toml=opts.config_toml(), progress=reporter)

    r = run_guarded(ctx, work)
    console.print(f"[green]wrote[/green] {r.path}: {plural(r.num_links, 'link')} x {len(r.freqs_hz)} freq "
                  f"({r.render_time_s:.1f} s rendering)", highlight=False)
    m = r.metrics
    if "mae_db" in m:
        table = Table("method", f"MAE on the test split, dB (n = {m['num_test']})", box=None, pad_edge=False)
        table.add_row("rfir (this model)", f"{m['mae_db']:.2f}")
        for k, text in (("nearest", "nearest training aspect"), ("linear", "linear interpolation of training aspects"),
                        ("nearest_range", "nearest training range, same aspect"),
                        ("linear_range", "linear interpolation in range, same aspect")):
            if f"baseline_{k}_mae_db" in m:
                table.add_row(f"baseline: {text}", f"{m[f'baseline_{k}_mae_db']:.2f}")
        console.print(table)
    fl = getattr(r, "flashes", None)   # specular peaks among the test rows (stages/predict/flashes.py)
    if fl and fl["num_flashes"]:
        console.print(f"flashes among the test rows (>= {fl['min_prominence_db']:g} dB prominent), within "
                      f"{fl['tolerance_db']:g} dB of their peak: " + ", ".join(
                          f"{name} {v['num_within_tolerance']}/{fl['num_flashes']}" for name, v in fl["methods"].items()),
                      highlight=False, soft_wrap=True)
    for w in filter(None, m.get("warning_baselines", "").split("; ")):
        console.print(f"[yellow]warning:[/yellow] {w}", highlight=False, soft_wrap=True)
    if r.plots:
        console.print(f"plots: {len(r.plots)} PNG in {Path(r.plots[0]).parent}", highlight=False)
    if r.results_json:
        console.print(f"results: {r.results_json}", highlight=False)
