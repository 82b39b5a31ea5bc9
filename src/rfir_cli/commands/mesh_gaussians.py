"""`rfir mesh-gaussians MESH.ply -o scene.h5`: surfel Gaussians tiled on a known mesh.

For users who already have geometry (CAD, LiDAR, simulate's ground truth): it skips the photo
stages and gives rf-fit a `scene` artifact directly.
"""
from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from ..context import console, run_guarded
from ..errors import ConfigError


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
        fields = gaussians_from_mesh(data.vertices, data.faces, spacing_m, labels=data.labels)
        names = None
        if data.labels is not None:
            top = int(data.labels.max()) + 1
            names = [data.label_names.get(i, f"label_{i}") for i in range(top)]
        path = write_scene_artifact(out, fields, label_names=names, source=str(mesh), spacing_m=spacing_m)
        return path, len(fields["gaussians/means"])

    path, count = run_guarded(ctx, work)
    console.print(f"[green]wrote[/green] {path}: {count} Gaussians at {spacing_m * 100:g} cm spacing", highlight=False)
