"""`rfir structure SCENE -o PLANES`: a room's planar structure (floor, ceiling, walls with their openings, object
segments) from its Gaussians, as a scene artifact rf-fit reads (rfir_stages.geom.structure)."""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.table import Table

from ..context import RichReporter, console, err_console, options, run_guarded


def register(app: typer.Typer) -> None:
    app.command("structure")(structure)


def structure(
    ctx: typer.Context,
    scene: Annotated[Path, typer.Argument(help="Scene artifact of a room (from `rfir geom`): Gaussians with normals, "
                                               "z up, metres.")],
    out: Annotated[Path, typer.Option("-o", "--out", metavar="FILE", help="Scene artifact to write (.h5).")],
    known_distance: Annotated[Optional[str], typer.Option(
        "--known-distance", metavar="A:B=METRES",
        help="A distance you measured between two of the surfaces printed (e.g. floor:ceiling=3.0, wall_00:wall_02"
             "=9.0): the scale error is reported.")] = None,
) -> None:
    """Find the room's planes in its Gaussians: floor, ceiling and walls meeting at their edges (tiled as flat
    surfels, openings left out), objects as boxes (their faces tiled) and the free Gaussians left; check that the
    floor is horizontal and the walls vertical ([geom.structure] settings)."""
    opts = options(ctx)

    def work():
        from rfir_core.artifacts import check_output
        from rfir_stages.geom.structure import run

        check_output(out, "scene", inputs=[scene])
        table = dict(opts.config().get("geom", {}).get("structure", {}))
        with RichReporter(opts.verbosity) as reporter:
            return run(scene, out, table, seed=opts.seed, progress=reporter, known_distance=known_distance)

    r = run_guarded(ctx, work)
    for line in r.warnings:
        err_console.print(f"[yellow]warning:[/yellow] {line}", highlight=False, soft_wrap=True)
    table = Table(title="structure: surfaces", box=None, pad_edge=False)
    for col in ("surface", "tilt [deg]", "offset [m]", "size [m]", "openings [m2]", "Gaussians"):
        table.add_column(col)
    for s in r.surfaces:
        tilt = "inferred (walls' top)" if s.inferred else f"{s.tilt_deg:.2f}"
        w, h = s.size_m
        table.add_row(s.name, tilt, f"{s.offset:.3f}", f"{w:.2f} x {h:.2f}", "-" if s.kind == "inset" else f"{s.openings_m2:.2f}",
                      str(len(s.members)))
    if opts.verbosity >= 0:
        console.print(table)
    if r.scale is not None:
        a, b, known, measured = r.scale
        console.print(f"scale: {a} to {b} measures {measured:.3f} m against {known:.3f} m known "
                      f"({100 * (measured / known - 1):+.2f} %)", highlight=False)
    console.print(f"[green]wrote[/green] {r.path}: {r.num_shell_surfels} shell surfels on {len(r.surfaces)} surfaces "
                  f"(from {r.num_on_shell} Gaussians), {r.num_in_objects} Gaussians in {r.num_objects} "
                  f"{'boxes' if r.boxes else f'object segments ({r.num_object_planes} object planes)'}, "
                  f"{r.num_free} free Gaussians of {r.num_in} "
                  f"in {r.seconds:.1f} s", highlight=False, soft_wrap=True)
