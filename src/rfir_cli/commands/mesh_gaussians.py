"""`rfir mesh-gaussians MESH.ply -o scene.h5`: surfel Gaussians tiled on a known mesh.

For users who already have geometry (CAD, LiDAR, simulate's ground truth): it skips the photo
stages and gives rf-fit a `scene` artifact directly.
"""
from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ..context import console, run_guarded
from ..errors import ConfigError, InputFileError


def degenerate_facet_warnings(report: dict) -> list[str]:
    """Lines for the facets gaussians_from_mesh skipped (zero area) or whose slivers it merged."""
    out = []
    if report.get("degenerate_faces"):
        out.append(f"{report['degenerate_faces']} of {report['faces']} facets have zero area: skipped")
    if report.get("sliver_surfels"):
        share = 100 * report["sliver_area_m2"] / max(report["area_m2"], 1e-300)
        out.append(f"{report['sliver_faces']} of {report['faces']} facets are slivers: their "
                   f"{report['sliver_surfels']} surfels narrower than {report['sliver_width_m'] * 1e3:.2g} mm "
                   f"({share:.0f} % of the area) were merged into {report['merged_surfels']} (area kept)")
    return out


def register(app: typer.Typer) -> None:
    app.command("mesh-gaussians")(mesh_gaussians)


def mesh_gaussians(
    ctx: typer.Context,
    mesh: Annotated[Path, typer.Argument(help="Triangle mesh (.ply, metres, world frame; optional per-face 'label').")],
    out: Annotated[Path, typer.Option("-o", "--out", help="Scene artifact to write (.h5).")],
    spacing_m: Annotated[float, typer.Option("--spacing", help="Largest surfel size [m] (~ lambda/4 to lambda/2).")] = 0.03,
) -> None:
    """Tile a mesh with flat Gaussians (normals from the faces) and write a scene artifact."""
    from rfir_stages.geom import gaussians_from_mesh, write_scene_artifact
    from rfir_stages.geom.mesh_io import read_ply_mesh

    def work():
        if not spacing_m > 0:
            raise ConfigError(f"--spacing must be positive, got {spacing_m}")
        data = read_ply_mesh(mesh)
        report: dict = {}
        try:
            fields = gaussians_from_mesh(data.vertices, data.faces, spacing_m, labels=data.labels, report=report)
        except ValueError as exc:   # a mesh with no face of non-zero area
            raise InputFileError(str(exc), path=mesh) from None
        names = None
        if data.labels is not None:
            top = int(data.labels.max()) + 1
            names = [data.label_names.get(i, f"label_{i}") for i in range(top)]
        path = write_scene_artifact(out, fields, label_names=names, source=str(mesh), spacing_m=spacing_m)
        return path, len(fields["gaussians/means"]), report

    path, count, report = run_guarded(ctx, work)
    for line in degenerate_facet_warnings(report):
        console.print(f"[yellow]warning:[/yellow] {line}", highlight=False)
    console.print(f"[green]wrote[/green] {path}: {count} Gaussians at {spacing_m * 100:g} cm spacing", highlight=False)
