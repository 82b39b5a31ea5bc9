"""Read a triangle mesh (PLY) with an optional per-face `label`, for `rfir mesh-gaussians`."""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rfir_core.errors import InputFileError


@dataclass
class Mesh:
    """vertices [V, 3] m, faces [F, 3] int, labels [F] int or None, label_names {label: name}; notes: what reading
    assumed (a turned axis), one line each."""

    vertices: np.ndarray
    faces: np.ndarray
    labels: np.ndarray | None
    label_names: dict[int, str]
    notes: list[str] = field(default_factory=list)


def read_ply_mesh(path: str | Path) -> Mesh:
    """Load vertices, triangles and face labels; a clear InputFileError for anything else.

    Label names come from a `labels.json` beside the file (as `rfir simulate` writes) when present.
    """
    from plyfile import PlyData

    path = Path(path)
    if not path.is_file():
        raise InputFileError("file not found", path=path)
    try:
        ply = PlyData.read(str(path))
    except Exception as exc:  # plyfile raises several types for a bad header
        raise InputFileError(f"not a readable PLY file ({exc})", path=path) from None
    if "vertex" not in ply or "face" not in ply or ply["face"].count == 0:
        raise InputFileError("PLY has no triangles (needs 'vertex' and 'face' elements)", path=path)
    vertex = ply["vertex"]
    vertices = np.stack([vertex["x"], vertex["y"], vertex["z"]], axis=1).astype(np.float64)
    face = ply["face"]
    index_name = next((n for n in ("vertex_indices", "vertex_index") if n in face.data.dtype.names), None)
    if index_name is None:
        raise InputFileError("face element has no vertex_indices", path=path)
    polygons = face[index_name]
    if any(len(p) != 3 for p in polygons):
        raise InputFileError("only triangle meshes are supported (found a face with != 3 vertices)", path=path)
    faces = np.asarray(np.stack(polygons), dtype=np.int64)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InputFileError("face indices outside the vertex list", path=path)
    if not np.all(np.isfinite(vertices)):
        raise InputFileError("vertex coordinates hold NaN or Inf", path=path)
    labels = np.asarray(face["label"], dtype=np.int64) if "label" in face.data.dtype.names else None
    return Mesh(vertices, faces, labels, _label_names(path.parent / "labels.json"))


def _label_names(path: Path) -> dict[int, str]:
    import json

    if not path.exists():
        return {}
    try:
        content = json.loads(path.read_text())
    except json.JSONDecodeError:
        return {}
    objects = content.get("objects", []) if isinstance(content, dict) else []
    return {int(o["label"]): str(o["name"]) for o in objects if isinstance(o, dict) and "label" in o and "name" in o}


def object_spacings(mesh: Mesh, spacing_m: float, object_cells: int) -> dict[int, float]:
    """Surfel spacing [m] of each labelled object: min(spacing_m, size / object_cells).

    size is the largest side of the object's axis-aligned bounding box [m]. A room's walls are tiled
    at spacing_m, while a desk or a chair gets about object_cells surfels across: its outline, the
    extent of its reflections and the rays it blocks are then resolved to a fraction 1/object_cells
    of its size rather than to the room's spacing (docs/guide/photos-to-scene.md).
    object_cells <= 0 or an unlabelled mesh: every face at spacing_m (key -1 for the unlabelled)."""
    if object_cells <= 0 or mesh.labels is None:
        return {-1: spacing_m} if mesh.labels is None else {int(v): spacing_m for v in np.unique(mesh.labels)}
    out = {}
    for value in np.unique(mesh.labels):
        corners = mesh.vertices[np.unique(mesh.faces[mesh.labels == value])]
        size = float(np.max(corners.max(0) - corners.min(0)))
        out[int(value)] = min(spacing_m, size / object_cells) if size > 0 else spacing_m
    return out


def surfels_per_object(mesh: Mesh, spacings: dict[int, float], report: dict | None = None,
                       rectangles: bool = False) -> dict[str, np.ndarray]:
    """Scene fields (`gaussians_from_mesh`, its `rectangles`) with each object tiled at its own spacing
    (object_spacings).

    report, when given, receives gaussians_from_mesh's counts summed over the objects."""
    from rfir_stages.geom import gaussians_from_mesh

    if mesh.labels is None:
        return gaussians_from_mesh(mesh.vertices, mesh.faces, spacings[-1], report=report, rectangles=rectangles)
    parts = []
    for value, spacing in sorted(spacings.items()):
        keep = mesh.labels == value
        part_report: dict = {}
        try:
            parts.append(gaussians_from_mesh(mesh.vertices, mesh.faces[keep], spacing, labels=mesh.labels[keep],
                                             report=part_report, rectangles=rectangles))
        except ValueError:   # an object whose facets all have zero area: counted, nothing to tile
            part_report = {"faces": int(keep.sum()), "degenerate_faces": int(keep.sum())}
        if report is not None:
            for k, v in part_report.items():
                report[k] = max(report.get(k, 0), v) if k == "sliver_width_m" else report.get(k, 0) + v
    if not parts:
        raise ValueError("the mesh has no face of non-zero area")
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def without_contact_faces(mesh: Mesh) -> tuple[Mesh, np.ndarray]:
    """(the mesh without the faces that rest against another object's surface (geom.contact_faces), the labels [K]
    of the faces left out); an unlabelled mesh is returned as it is."""
    from .contact_faces import contact_faces

    contact = contact_faces(mesh.vertices, mesh.faces, mesh.labels)
    if not contact.any():
        return mesh, np.zeros(0, np.int64)
    return (Mesh(mesh.vertices, mesh.faces[~contact], mesh.labels[~contact], mesh.label_names, mesh.notes),
            mesh.labels[contact])
