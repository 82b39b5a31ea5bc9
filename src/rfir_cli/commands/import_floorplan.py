"""`rfir import floorplan walls.csv -o room.ply --height 2.7`: a 2D floor plan -> a labelled room mesh.

The mesh and its labels.json are what `rfir mesh-gaussians room.ply -o scene.h5 --preset room` reads
(rfir_stages.importers.floorplan; docs/guide/rssi-survey.md).
"""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from ..context import console, options, run_guarded
from .import_ import import_app


def register(app: typer.Typer) -> None:
    """Add `floorplan` to `rfir import` (the group itself is registered by commands.import_)."""
    import_app.command("floorplan")(import_floorplan_command)


def import_floorplan_command(
    ctx: typer.Context,
    file: Annotated[Path, typer.Argument(
        metavar="WALLS.CSV", help="CSV, one wall a row: x0,y0,x1,y1,thickness_m,material[,height_m,z0_m] (metres; the "
        "wall's centre line on the plan).")],
    out: Annotated[Path, typer.Option(
        "-o", "--out", metavar="ROOM.PLY", help="Mesh to write (.ply); labels.json goes beside it.")],
    height_m: Annotated[float, typer.Option(
        "--height", metavar="METRES", help="Room height [m]: the walls' default height and the ceiling's underside.")],
    slab_m: Annotated[float, typer.Option("--slab", metavar="METRES", help="Floor and ceiling thickness [m].")] = 0.2,
    walls: Annotated[str, typer.Option(
        "--walls", metavar="sheet|box", help="sheet: one two-sided rectangle on each wall's centre line (floor and "
        "ceiling one rectangle each), as the room model reads a surface: one slab of the wall's material; box: each "
        "wall a closed box of its thickness (for renders: the room model would cross each wall as two slabs).")] = "sheet",
    floor_material: Annotated[Optional[str], typer.Option(
        "--floor-material", metavar="NAME", help="Name the floor's material (label floor_<material>, e.g. concrete: "
        "rf-fit starts it there); default: label 'floor'.")] = None,
    ceiling_material: Annotated[Optional[str], typer.Option(
        "--ceiling-material", metavar="NAME", help="Name the ceiling's material (label ceiling_<material>).")] = None,
) -> None:
    """Build a room mesh from a floor plan of wall segments (columns: docs/guide/rssi-survey.md)."""
    from rfir_stages.importers.floorplan import import_floorplan

    from rfir_core.artifacts import check_output

    overwrite = bool(getattr(options(ctx), "force", False))

    def work():
        check_output(out, None, inputs=[file])          # never over the plan itself
        return import_floorplan(file, out, height_m, slab_m, walls, floor_material, ceiling_material,
                                overwrite=overwrite)

    result = run_guarded(ctx, work)
    objects = result.mesh.objects
    classes: dict[str, int] = {}
    for wall in result.walls:
        classes[wall.material] = classes.get(wall.material, 0) + 1
    size = result.mesh.bounds[1] - result.mesh.bounds[0]
    shown = ", ".join(f"{name} {n}" for name, n in classes.items())
    console.print(f"[green]wrote[/green] {result.path} and {result.labels_path.name}: {len(result.walls)} walls "
                  f"({shown}) as {'sheets' if walls == 'sheet' else 'boxes'} (--walls), {objects[-2]['name']} and {objects[-1]['name']} over {size[0]:.2f} x {size[1]:.2f} m, "
                  f"{height_m:g} m high; {len(result.mesh.faces)} triangles, {len(objects)} labels",
                  highlight=False, soft_wrap=True)
    unnamed = [name for name in classes if not any(o["radio_material"] for o in objects
                                                    if o["name"].startswith(name + "_"))]
    if unnamed:
        console.print(f"note: no ITU material in the name of {', '.join(unnamed)}: rf-fit starts "
                      f"{'them' if len(unnamed) > 1 else 'it'} from its default material (names such as concrete, "
                      "brick, plasterboard, wood, glass, metal set the start)", highlight=False, soft_wrap=True)
    console.print(f"next: rfir mesh-gaussians {result.path} -o scene.h5 --preset room", highlight=False,
                  markup=False, soft_wrap=True)
