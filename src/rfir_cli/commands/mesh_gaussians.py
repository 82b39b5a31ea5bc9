"""`rfir mesh-gaussians MESH -o scene.h5 [--preset room|object]`: surfel Gaussians tiled on a known mesh
(PLY, OBJ, STL, glTF/GLB: rfir_stages.geom.mesh_formats).

For users who already have geometry (CAD, LiDAR, simulate's ground truth): it skips the photo
stages and gives rf-fit a `scene` artifact directly.
"""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import numpy as np
import typer

from ..context import console, run_guarded
from rfir_core.errors import ConfigError, InputFileError


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


def contact_words(mesh, contact) -> str:
    """The line that says which faces were left out as resting against another object; contact [K]: their labels."""
    if len(contact) == 0:
        return "--drop-contact-faces: no face rests against another object's surface"
    labels, counts = np.unique(contact, return_counts=True)
    named = [f"{mesh.label_names.get(int(lab), f'label_{lab}')} {n}" for lab, n in zip(labels, counts)]
    shown = ", ".join(named[:6]) + (f" and {len(named) - 6} more objects" if len(named) > 6 else "")
    return (f"left out {len(contact)} faces that rest against another object's surface (hidden: a box's "
            f"bottom on the floor): {shown}")


# Tiling presets: (spacing [m], object cells, rectangles, drop contact faces). "object" is the tiling the RCS checks
# were made on; "room" the room recipe of docs/guide/photos-to-scene.md.
PRESETS = {"room": (0.8, 12, True, True), "object": (0.03, 0, False, False)}
LARGE_COUNT = 100_000   # no preset given and more Gaussians than this estimated: a warning naming --preset room


def preset_values(preset: str | None, spacing_m, object_cells, rectangles, drop_contact_faces) -> tuple:
    """(spacing [m], object cells, rectangles, drop contact faces): the preset's values (no preset: "object"'s)
    where the flag was not given (None)."""
    if preset is not None and preset not in PRESETS:
        raise ConfigError(f"--preset must be one of {', '.join(PRESETS)}, got {preset!r}")
    base = PRESETS[preset or "object"]
    given = (spacing_m, object_cells, rectangles, drop_contact_faces)
    return tuple(b if g is None else g for b, g in zip(base, given))


def estimated_count(mesh, spacing_m: float) -> int:
    """Gaussians the triangle tiling at spacing_m [m] makes (each face split into ceil(longest edge / spacing)^2
    sub-triangles, as gaussians_from_mesh does), before any merging."""
    tri = mesh.vertices[mesh.faces]
    longest = np.linalg.norm(tri - tri[:, [1, 2, 0]], axis=2).max(axis=1)
    return int((np.maximum(1, np.ceil(longest / spacing_m - 1e-9)) ** 2).sum())


def register(app: typer.Typer) -> None:
    app.command("mesh-gaussians")(mesh_gaussians)


def mesh_gaussians(
    ctx: typer.Context,
    mesh: Annotated[Path, typer.Argument(help="Triangle mesh in metres, z up: .ply (per-face 'label', names from "
                                              "labels.json beside it), .obj (o/g names as labels), .stl, .gltf/.glb "
                                              "(one label per node; y up, turned to z up).")],
    out: Annotated[Path, typer.Option("-o", "--out", help="Scene artifact to write (.h5).")],
    spacing_m_flag: Annotated[Optional[float], typer.Option(
        "--spacing", help="Largest surfel size [m]: about lambda/4 of the highest frequency you will predict "
                          "(3 cm at 2.4 GHz, 1.5 cm for 5.8 GHz; surfels coarser than lambda/2 miss its lobes). "
                          "Default: the preset's (room 0.8, object 0.03).")] = None,
    object_cells_flag: Annotated[Optional[int], typer.Option(
        "--object-cells", help="Tile each labelled object at min(--spacing, its size / N), so that small objects "
        "(furniture in a room) get about N surfels across; 0: every face at --spacing. Default: the preset's "
        "(room 12, object 0).")] = None,
    rectangles_flag: Annotated[Optional[bool], typer.Option(
        "--rectangles/--no-rectangles", help="Tile each pair of triangles that forms a rectangle (a box's face, a wall "
        "panel) as the rectangle's cells, at most spacing / 2 a side, so that surfaces end at their edges: for rooms "
        "(docs/guide/photos-to-scene.md). Off: every face split into smaller triangles (the tiling the RCS checks were made on). "
        "Default: the preset's (room on, object off).")] = None,
    drop_contact_faces_flag: Annotated[Optional[bool], typer.Option(
        "--drop-contact-faces/--no-drop-contact-faces", help="Leave out the faces of a labelled mesh that rest against "
        "another object's surface (a box's bottom on the floor: hidden; rfir_stages.geom.contact_faces): for rooms (docs/guide/photos-to-scene.md). "
        "Off: every face kept (as the RCS checks were made). Default: the preset's (room on, object off).")] = None,
    preset: Annotated[Optional[str], typer.Option(
        "--preset", metavar="room|object",
        help="room: --spacing 0.8 --object-cells 12 --rectangles --drop-contact-faces (docs/guide/photos-to-scene.md); "
        "object: --spacing 0.03, no object cells, rectangles or dropped faces (the RCS tiling; also the default). "
        "Flags given as well override the preset's.")] = None,
    up: Annotated[Optional[str], typer.Option(
        "--up", metavar="z|y", help="Axis that points up in the mesh file, z or y (turned to rfir's z up). Default: y "
        "for glTF, "
        "z for the rest.")] = None,
) -> None:
    """Tile a mesh with flat Gaussians (normals from the faces) and write a scene artifact."""
    from rfir_stages.geom import write_scene_artifact
    from rfir_stages.geom.mesh_formats import read_mesh
    from rfir_stages.geom.mesh_io import object_spacings, surfels_per_object, without_contact_faces

    spacing_m, object_cells, rectangles, drop_contact_faces = run_guarded(ctx, lambda: preset_values(
        preset, spacing_m_flag, object_cells_flag, rectangles_flag, drop_contact_faces_flag))

    def work():
        nonlocal object_cells, drop_contact_faces
        from rfir_core.artifacts import check_output

        check_output(out, "scene", inputs=[mesh])   # before any work: never over the mesh, nor another kind
        if not spacing_m > 0:
            raise ConfigError(f"--spacing must be positive, got {spacing_m}")
        if object_cells < 0:
            raise ConfigError(f"--object-cells must be 0 (off) or positive, got {object_cells}")
        data = read_mesh(mesh, up)
        for note in data.notes:
            console.print(f"{mesh}: {note}", highlight=False, markup=False, soft_wrap=True)
        unset = [name for name, value, flag in (("--object-cells", object_cells, object_cells_flag),
                                                 ("--drop-contact-faces", drop_contact_faces, drop_contact_faces_flag))
                 if value and flag is None]
        if data.labels is None and unset:      # the preset's, not asked for: left out with a line
            object_cells = object_cells if object_cells_flag is not None else 0
            drop_contact_faces = drop_contact_faces if drop_contact_faces_flag is not None else False
            console.print(f"{mesh}: no labels (one object per label), so --preset {preset} goes without "
                          f"{' and '.join(unset)} (every face at --spacing {spacing_m:g}, every face kept)",
                          highlight=False, markup=False, soft_wrap=True)
        if preset is None and spacing_m_flag is None:
            count = estimated_count(data, spacing_m)
            if count > LARGE_COUNT:
                size = data.vertices.max(0) - data.vertices.min(0)
                console.print(f"[yellow]warning:[/yellow] no --preset: the object tiling at {spacing_m * 100:g} cm makes "
                              f"up to {count:,} Gaussians on this {size[0]:.3g} x {size[1]:.3g} x {size[2]:.3g} m "
                              "mesh; for a room use --preset room (0.8 m, furniture at size / 12), or set --spacing",
                              highlight=False, soft_wrap=True)
        resting = ""
        if drop_contact_faces:
            if data.labels is None:
                raise InputFileError("--drop-contact-faces needs a per-face 'label' (one object per label); the mesh "
                                     "has none", path=mesh)
            data, contact = without_contact_faces(data)
            resting = contact_words(data, contact)
        if object_cells and data.labels is None:
            raise InputFileError("--object-cells needs a per-face 'label' (one object per label); the mesh has none",
                                 path=mesh)
        spacings = object_spacings(data, spacing_m, object_cells)
        report: dict = {}
        try:
            fields = surfels_per_object(data, spacings, report=report, rectangles=rectangles)
        except ValueError as exc:   # a mesh with no face of non-zero area
            raise InputFileError(str(exc), path=mesh) from None
        names = None
        if data.labels is not None:
            top = int(data.labels.max()) + 1
            names = [data.label_names.get(i, f"label_{i}") for i in range(top)]
        finer = sorted(v for v in spacings.values() if v < spacing_m)
        described = spacing_m if not finer else f"{spacing_m} (objects: min(spacing, size / {object_cells}))"
        path = write_scene_artifact(out, fields, label_names=names, source=str(mesh), spacing_m=described,
                                    rectangles=rectangles, contact_faces_left_out=drop_contact_faces)
        return path, len(fields["gaussians/means"]), report, finer, resting

    path, count, report, finer, resting = run_guarded(ctx, work)
    if resting:
        console.print(resting, highlight=False)
    for line in degenerate_facet_warnings(report):
        console.print(f"[yellow]warning:[/yellow] {line}", highlight=False)
    extra = (f"; {len(finer)} smaller objects at {finer[0] * 100:.3g}-{finer[-1] * 100:.3g} cm (size / {object_cells})"
             if finer else "")
    tiling = f"; {report.get('rectangles', 0)} rectangles tiled as cells" if rectangles else ""
    chosen = f"preset {preset}" if preset else "no --preset: flags not given at the object preset's values"
    console.print(f"[green]wrote[/green] {path}: {count} Gaussians at {spacing_m * 100:g} cm spacing{extra}{tiling} "
                  f"({chosen})", highlight=False)
