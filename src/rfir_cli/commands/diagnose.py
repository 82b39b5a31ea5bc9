"""`rfir diagnose MODEL MEASUREMENTS -o REPORT/`: name the effect the model misses, add it, show the gap shrink."""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from ..context import RichReporter, console, options, run_guarded


def register(app: typer.Typer) -> None:
    app.command("diagnose")(diagnose)


def diagnose(
    ctx: typer.Context,
    model: Annotated[Path, typer.Argument(help="rf artifact, or a predictions / measurements artifact of the same "
                                               "links (any method's prediction, e.g. a ray tracer's).")],
    measurements: Annotated[Path, typer.Argument(help="measurements artifact to explain.")],
    out: Annotated[Path, typer.Option("-o", "--out", metavar="DIR",
            help="Report folder: report.md, results.json, effects.json, PNGs.")],
    geometry: Annotated[Optional[Path], typer.Option(
        "--geometry", metavar="FILE", help="scene or rf artifact whose Gaussians say which links are shadowed (default: MODEL "
                           "when it is an rf artifact).")] = None,
    max_effects: Annotated[int, typer.Option("--max-effects", metavar="N", help="Stop after naming this many effects.")] = 4,
) -> None:
    """Break the residual down, name the missing effect from the catalogue, add it, refit, repeat."""
    opts = options(ctx)

    def work():
        from rfir_stages.diagnose import run

        with RichReporter(opts.verbosity) as reporter:
            return run(model, measurements, out, geometry_path=geometry, max_effects=max_effects, seed=opts.seed,
                       config_toml=opts.config_toml(), progress=reporter)

    r = run_guarded(ctx, work)
    if r.frequencies:
        console.print(f"predicted at {r.frequencies}", highlight=False, markup=False)
    console.print(r.headline, highlight=False, markup=False)
    for i, n in enumerate(r.named, 1):
        params = ", ".join(f"{k} = {v:.4g}" for k, v in n["params"].items())
        console.print(f"{i}. [bold]{n['effect']}[/bold] ({n['title']}; confidence {n['confidence']:.0%}): {params}",
                      highlight=False)
    console.print(f"held-out MAE {r.mae_before_db:.2f} -> {r.mae_after_db:.2f} dB; report {r.out_dir / 'report.md'} "
                  f"({r.wall_s:.1f} s)", highlight=False)
