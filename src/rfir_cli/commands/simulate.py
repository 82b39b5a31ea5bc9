"""`rfir simulate SCENE OUT/`: ground-truth data sets (meshes, photos, poses, radio measurements)."""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from ..context import RichReporter, console, options, run_guarded


def register(app: typer.Typer) -> None:
    app.command("simulate")(simulate)


def simulate(
    ctx: typer.Context,
    scene: Annotated[str, typer.Argument(
        help="classroom, flat, office, lego, car, h-target, trio (or the test scenes plate, empty).")],
    out: Annotated[Path, typer.Argument(help="Output folder (created).")],
    quick: Annotated[bool, typer.Option("--quick", help="Reduced sizes (few aspects, receivers, views).")] = False,
    task: Annotated[Optional[list[str]], typer.Option(
        "--task", metavar="TASK", help="rssi, rcs or wideband (repeatable); default from the scene.")] = None,
    no_photos: Annotated[bool, typer.Option("--no-photos", help="Skip the photo rendering.")] = False,
    rcs_backend: Annotated[Optional[str], typer.Option(
        "--rcs-backend", metavar="sionna|po",
                help="Solver of the rcs/wideband tasks: sionna (ray tracing, GO) or po (physical optics); "
                              "default simulate.rcs_backend.")] = None,
    workers: Annotated[Optional[int], typer.Option(
        "--workers", metavar="N", help="Processes for the Sionna rcs/wideband solves (1 = in-process); "
                          "default simulate.workers.")] = None,
    scene_edit: Annotated[Optional[list[str]], typer.Option(
        "--scene-edit", metavar="NAMES:OP", help="Edit the scene before simulating (repeatable, in order): NAMES:OP, e.g. "
                             "'whiteboard:delete', 'wall_back:material:metal', 'desk_0[0369]:translate:0,1,0'.")] = None,
) -> None:
    """Simulate SCENE: write meshes/, images/ + cameras.h5, and measurements.h5 into OUT."""
    opts = options(ctx)

    def work():
        from rfir_stages.simulate import run

        config = opts.config()
        table = dict(config.get("simulate", {}))
        if task:
            table["tasks"] = list(task)
        if no_photos:
            table["photos"] = False
        if rcs_backend is not None:
            table["rcs_backend"] = rcs_backend
        if workers is not None:
            table["workers"] = workers
        if scene_edit:
            table["scene_edits"] = list(table.get("scene_edits", [])) + list(scene_edit)
        with RichReporter(opts.verbosity) as reporter:
            return run(scene, out, table, config_toml=opts.config_toml(), quick=quick or None, progress=reporter)

    result = run_guarded(ctx, work)
    _report(result)


def _report(result) -> None:
    table = Table("output", "what", "time", box=None, pad_edge=False)
    table.add_row(str(result.out_dir / "meshes"), f"{len(result.meshes)} PLY meshes",
                  f"{result.timings_s.get('meshes', 0):.1f}s")
    if result.cameras is not None:
        table.add_row(str(result.cameras), f"{result.images} photos + poses", f"{result.timings_s.get('photos', 0):.1f}s")
    for task, path in result.measurements.items():
        table.add_row(str(path), f"{task}: {result.links[task]} links x {result.freqs[task]} freqs",
                      f"{result.timings_s.get(task, 0):.1f}s")
    console.print(f"[green]simulated[/green] {result.scene}", highlight=False)
    console.print(table)
    if result.backends:
        console.print("solver: " + ", ".join(f"{t} {b}" for t, b in result.backends.items()), highlight=False)
    for n in result.notes:
        console.print(n, highlight=False)
    for w in result.warnings:
        console.print(f"[yellow]warning:[/yellow] {w}", highlight=False)
