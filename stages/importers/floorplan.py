"""A 2D floor plan (wall segments in a CSV) -> a labelled triangle mesh of the room, for `rfir mesh-gaussians`.

CSV (comma-separated, one header row naming the columns in any order; blank lines and lines starting with '#'
skipped), one wall segment per row, lengths in metres:

    x0,y0,x1,y1,thickness_m,material[,height_m][,z0_m]

(x0, y0) -> (x1, y1) is the wall's centre line on the floor plan, thickness_m its thickness, material a name
that becomes the wall's label class (walls of one material share one fitted material in rf-fit). Optional
height_m (default: the room height) and z0_m (default 0, the floor) make a partial-height row: a parapet, a
glass pane above it, the wall above a door. Every wall is a closed box (walls="box": 12 triangles, each face its
own vertices, faces wound counter-clockwise seen from outside) from end to end of its centre line, so where two
centre lines meet at a corner the room side of the corner is exact and the boxes overlap inside the corner (with
a notch of half a thickness outside it). walls="sheet" makes each wall one two-sided rectangle on its centre
line, its thickness recorded in labels.json only (the simulator's scenes model walls so).

The floor and the ceiling are slabs (boxes of slab_m; sheets with walls="sheet") over the bounding box of the
walls: the floor's top at z = 0, the ceiling's bottom at z = height_m.

Labels: each wall `<material>_NN` (NN counting the walls of that material from 00; the material lower-cased,
other characters than letters and digits turned to '_'), then `floor` and `ceiling` (or `floor_<material>`,
`ceiling_<material>` when their materials are given). rf-fit's classes drop the trailing _NN
(`label_class_names`), and a class whose name contains an ITU-R P.2040 material (concrete, brick, plasterboard,
wood, glass, metal, ...) starts its fit from that material (`room_stage.name_priors`).
"""
from __future__ import annotations

import csv
import io
import json
import math
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rfir_core.errors import ConfigError, InputFileError
from rfir_stages.model.tabulated import named_material
from rfir_stages.simulate.scenes import write_ply

REQUIRED = ("x0", "y0", "x1", "y1", "thickness_m", "material")
OPTIONAL = ("height_m", "z0_m")
WALL_KINDS = ("box", "sheet")
MIN_LENGTH_M = 1e-3
WRITER = "rfir import floorplan"


@dataclass
class Wall:
    """One CSV row: centre line (x0, y0) -> (x1, y1) [m], thickness_m, material (the cleaned name), height_m and
    z0_m [m] (its bottom above the floor), line: the CSV line it came from."""

    x0: float
    y0: float
    x1: float
    y1: float
    thickness_m: float
    material: str
    height_m: float
    z0_m: float
    line: int

    @property
    def length_m(self) -> float:
        return math.hypot(self.x1 - self.x0, self.y1 - self.y0)


@dataclass
class FloorplanMesh:
    """vertices [V, 3] m, faces [F, 3] int, labels [F] int, objects: one dict per label (label, name,
    radio_material: the ITU material the name names or None, thickness_m, faces), bounds [[x, y, z] min, max] m."""

    vertices: np.ndarray
    faces: np.ndarray
    labels: np.ndarray
    objects: list[dict]
    bounds: np.ndarray


@dataclass
class FloorplanResult:
    """What import_floorplan wrote: the PLY, the labels.json beside it, and the mesh."""

    path: Path
    labels_path: Path
    mesh: FloorplanMesh
    walls: list[Wall] = field(default_factory=list)


def material_name(text: str) -> str:
    """A material as a label's stem: lower case, runs of other characters than letters and digits as '_'."""
    return re.sub(r"[^a-z0-9]+", "_", text.strip().lower()).strip("_")


def read_floorplan_csv(path: str | Path, height_m: float) -> list[Wall]:
    """Every wall of the CSV, or an InputFileError naming the file, the line and the problem (nothing else read).

    height_m: the room height [m], the default and the upper bound of each row's z0_m + height_m."""
    path = Path(path)
    if not path.is_file():
        raise InputFileError("file not found", path=path)
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise InputFileError("not a text file (UTF-8 expected)", path=path) from None
    rows = [(number, row) for number, row in enumerate(csv.reader(io.StringIO(text)), start=1)
            if row and any(c.strip() for c in row) and not row[0].lstrip().startswith("#")]
    if not rows:
        raise InputFileError(f"no header row (columns {','.join(REQUIRED)}[,{','.join(OPTIONAL)}])", path=path)
    head_line, header = rows[0]
    columns = [c.strip().lower() for c in header]
    missing = [c for c in REQUIRED if c not in columns]
    unknown = [c for c in columns if c not in REQUIRED + OPTIONAL]
    if missing or unknown:
        problem = (f"missing column{'s' if len(missing) > 1 else ''} {', '.join(missing)}" if missing else
                   f"unknown column{'s' if len(unknown) > 1 else ''} {', '.join(repr(c) for c in unknown)}")
        raise InputFileError(f"line {head_line}: {problem} (columns: {','.join(REQUIRED)}, optional "
                             f"{','.join(OPTIONAL)})", path=path)
    if len(set(columns)) != len(columns):
        raise InputFileError(f"line {head_line}: a column is named twice", path=path)
    walls = []
    for number, row in rows[1:]:
        if len(row) != len(columns):
            raise InputFileError(f"line {number}: {len(row)} fields, the header has {len(columns)}", path=path)
        cells = {c: v.strip() for c, v in zip(columns, row)}

        def number_of(name: str, default: float | None = None) -> float:
            value = cells.get(name, "")
            if value == "" and default is not None:
                return default
            try:
                out = float(value)
            except ValueError:
                raise InputFileError(f"line {number}: {name} {value!r} is not a number", path=path) from None
            if not math.isfinite(out):
                raise InputFileError(f"line {number}: {name} is {value} (a finite number is needed)", path=path)
            return out

        x0, y0, x1, y1 = (number_of(c) for c in ("x0", "y0", "x1", "y1"))
        thickness = number_of("thickness_m")
        height = number_of("height_m", height_m)
        z0 = number_of("z0_m", 0.0)
        material = material_name(cells["material"])
        wall = Wall(x0, y0, x1, y1, thickness, material, height, z0, number)
        problem = None
        if not material:
            problem = f"material {cells['material']!r} is empty (name it: concrete, glass, wood, ...)"
        elif wall.length_m < MIN_LENGTH_M:
            problem = f"zero-length wall ({x0:g}, {y0:g}) -> ({x1:g}, {y1:g})"
        elif not thickness > 0:
            problem = f"thickness_m must be positive, got {thickness:g}"
        elif not height > 0:
            problem = f"height_m must be positive, got {height:g}"
        elif z0 < 0:
            problem = f"z0_m must be 0 (on the floor) or above, got {z0:g}"
        elif z0 + height > height_m + 1e-9:
            problem = f"the wall reaches {z0 + height:g} m, above the ceiling at {height_m:g} m (--height)"
        if problem:
            raise InputFileError(f"line {number}: {problem}", path=path)
        walls.append(wall)
    if not walls:
        raise InputFileError(f"line {head_line}: a header but no walls", path=path)
    return walls


def _prism(corners: np.ndarray, z0: float, z1: float) -> tuple[np.ndarray, np.ndarray]:
    """Closed box over a convex footprint corners [4, 2] (counter-clockwise) from z0 to z1 [m]: 24 vertices (each
    face its own), 12 triangles wound counter-clockwise seen from outside."""
    a, b, c, d = (np.asarray(p, dtype=np.float64) for p in corners)
    lo = [np.array([*p, z0]) for p in (a, b, c, d)]
    hi = [np.array([*p, z1]) for p in (a, b, c, d)]
    quads = [(lo[0], lo[3], lo[2], lo[1]), (hi[0], hi[1], hi[2], hi[3])]        # bottom (-z), top (+z)
    quads += [(lo[i], lo[(i + 1) % 4], hi[(i + 1) % 4], hi[i]) for i in range(4)]   # sides, outward
    return _quads(quads)


def _quads(quads) -> tuple[np.ndarray, np.ndarray]:
    """Triangles (q0, q1, q2), (q0, q2, q3) of each quad, each quad its own four vertices."""
    vertices = np.asarray([p for q in quads for p in q], dtype=np.float64)
    base = 4 * np.arange(len(quads))[:, None]
    faces = np.concatenate([base + [0, 1, 2], base + [0, 2, 3]], axis=1).reshape(-1, 3)
    return vertices, faces


def wall_footprint(wall: Wall) -> np.ndarray:
    """[4, 2] corners [m] of the wall's box on the plan, counter-clockwise: its centre line +- thickness / 2."""
    p0, p1 = np.array([wall.x0, wall.y0]), np.array([wall.x1, wall.y1])
    u = (p1 - p0) / wall.length_m
    n = np.array([-u[1], u[0]]) * wall.thickness_m / 2
    return np.stack([p0 - n, p1 - n, p1 + n, p0 + n])


def check_options(height_m: float, slab_m: float, walls_kind: str) -> None:
    """A ConfigError naming the option for a room height or slab thickness [m] that is not positive and finite, or
    an unknown wall kind."""
    if walls_kind not in WALL_KINDS:
        raise ConfigError(f"--walls must be one of {', '.join(WALL_KINDS)}, got {walls_kind!r}")
    if not (height_m > 0 and math.isfinite(height_m)):
        raise ConfigError(f"--height must be positive, got {height_m:g}")
    if not (slab_m > 0 and math.isfinite(slab_m)):
        raise ConfigError(f"--slab must be positive, got {slab_m:g}")


def floorplan_mesh(walls: list[Wall], height_m: float, slab_m: float = 0.2, walls_kind: str = "sheet",
                   floor_material: str | None = None, ceiling_material: str | None = None) -> FloorplanMesh:
    """The room's mesh: each wall (box or sheet, module docstring), then the floor (top at z = 0) and the ceiling
    (bottom at z = height_m [m]) over the walls' bounding box, slab_m [m] thick."""
    check_options(height_m, slab_m, walls_kind)

    parts, objects, counts = [], [], {}

    def add(name, vertices, faces, thickness_m):
        objects.append({"label": len(objects), "name": name, "radio_material": named_material(name),
                        "thickness_m": float(thickness_m), "faces": int(len(faces))})
        parts.append((vertices, faces))

    for wall in walls:
        k = counts.get(wall.material, 0)
        counts[wall.material] = k + 1
        corners = wall_footprint(wall)
        if walls_kind == "box":
            v, f = _prism(corners, wall.z0_m, wall.z0_m + wall.height_m)
        else:
            p0, p1 = (corners[0] + corners[3]) / 2, (corners[1] + corners[2]) / 2
            z0, z1 = wall.z0_m, wall.z0_m + wall.height_m
            v, f = _quads([(np.array([*p0, z0]), np.array([*p1, z0]), np.array([*p1, z1]), np.array([*p0, z1]))])
        add(f"{wall.material}_{k:02d}", v, f, wall.thickness_m)
    plan = np.concatenate([wall_footprint(w) for w in walls])
    (x0, y0), (x1, y1) = plan.min(0), plan.max(0)
    rect = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])
    for name, material, z_in, outward in (("floor", floor_material, 0.0, -1), ("ceiling", ceiling_material,
                                                                                  height_m, 1)):
        if walls_kind == "box":
            z_out = z_in + outward * slab_m
            v, f = _prism(rect, min(z_in, z_out), max(z_in, z_out))
        else:   # one rectangle facing into the room
            ring = rect if outward < 0 else rect[::-1]
            v, f = _quads([[np.array([*p, z_in]) for p in ring]])
        cleaned = material_name(material) if material else ""
        add(f"{name}_{cleaned}" if cleaned else name, v, f, slab_m)
    vertices = np.concatenate([p[0] for p in parts])
    offsets = np.cumsum([0] + [len(p[0]) for p in parts[:-1]])
    faces = np.concatenate([p[1] + o for p, o in zip(parts, offsets)])
    labels = np.concatenate([np.full(len(p[1]), i, np.int64) for i, p in enumerate(parts)])
    return FloorplanMesh(vertices, faces, labels, objects, np.stack([vertices.min(0), vertices.max(0)]))


def _check_replace(out: Path, labels_path: Path) -> None:
    """Refuse (InputFileError) to replace OUT or the labels.json beside it unless both are this importer's own
    output for OUT (a rerun): labels.json is shared by every mesh in its folder."""
    ours = False
    if labels_path.exists():
        try:
            content = json.loads(labels_path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            content = None
        ours = isinstance(content, dict) and content.get("written_by") == WRITER and content.get("scene") == out.stem
        if not ours:
            scene = content.get("scene") if isinstance(content, dict) else None
            named = f" (labels of {scene!r})" if scene else ""
            raise InputFileError(f"exists{named}, and the room's labels would replace it: nothing written (write the "
                                 "room into a folder of its own, or pass --force)", path=labels_path)
    if out.exists() and not ours:
        raise InputFileError("exists and is not a mesh this importer wrote: nothing written (choose another name, "
                             "or pass --force)", path=out)


def import_floorplan(csv_path: str | Path, out: str | Path, height_m: float, slab_m: float = 0.2,
                     walls_kind: str = "sheet", floor_material: str | None = None,
                     ceiling_material: str | None = None, overwrite: bool = False) -> FloorplanResult:
    """Read the plan, build its mesh, and write OUT (.ply: float x, y, z per vertex, an int `label` per vertex and
    per face) and labels.json beside it (label -> name, as `rfir simulate` writes it and mesh-gaussians reads it).
    Nothing is written unless the whole plan is valid; an existing OUT or labels.json is kept unless overwrite."""

    out = Path(out)
    if out.suffix.lower() != ".ply":
        raise ConfigError(f"-o {out}: the mesh is written as PLY (name it .ply)")
    labels_path = out.parent / "labels.json"
    check_options(height_m, slab_m, walls_kind)
    walls = read_floorplan_csv(csv_path, height_m)
    mesh = floorplan_mesh(walls, height_m, slab_m, walls_kind, floor_material, ceiling_material)
    if not overwrite:
        _check_replace(out, labels_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    vertex_label = np.zeros(len(mesh.vertices), np.int32)
    vertex_label[mesh.faces.reshape(-1)] = np.repeat(mesh.labels, 3)
    temp_ply, temp_json = out.with_name(out.name + ".part"), labels_path.with_name("labels.json.part")
    try:
        write_ply(temp_ply, mesh.vertices.astype(np.float32), mesh.faces, vertex_label, mesh.labels.astype(np.int32))
        temp_json.write_text(json.dumps({"scene": out.stem, "written_by": WRITER, "source": Path(csv_path).name,
                                         "walls": walls_kind, "height_m": height_m, "objects": mesh.objects},
                                        indent=1))
        os.replace(temp_ply, out)
        os.replace(temp_json, labels_path)
    finally:
        for temp in (temp_ply, temp_json):
            temp.unlink(missing_ok=True)
    return FloorplanResult(out, labels_path, mesh, walls)
