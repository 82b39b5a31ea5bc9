"""`rfir structure SCENE -o PLANES`: a room's planar structure from its Gaussians (planes.py, room_shell.py), written
as a `scene` artifact that rf-fit reads as it reads any other.

The shell (floor, ceiling, walls) is tiled anew with flat square surfels over each surface's extent, openings
left out (from_mesh.gaussians_from_mesh on the extent's rectangles, at `spacing_m` as `mesh-gaussians --preset
room` tiles a mesh), so that the room model's patches are its planes with their edges (`tile_shell = false`:
the shell's own Gaussians projected onto their surfaces instead). The Gaussians off the shell inside it are
joined into object segments (DBSCAN), each cut into boxes whose faces are tiled as the shell is (object_boxes.py;
`tile_shell = false`: the boxes' Gaussians projected onto their nearest faces); a segment that is not box-like
stays free Gaussians. With `objects = "keep"` the segments stay Gaussians instead, those on one of the object
planes (levelled or plumbed within snap_deg, as the shell's) projected onto it, with the plane's normal and their
footprint flattened into it. Rectangles of the shell of another colour or depth (a door, window panes, a board)
become insets, grouped across the room into classes by appearance (insets.py; `insets = false`: none). Gaussians
in no segment or box, and those behind the shell, stay as they were, unlabelled (-1; `keep_free = false`: left
out): the free Gaussians. Labels are named by class (floor, ceiling, wall_NN, inset_A_NN, object_NN), so rf-fit's
class sharing gives one material to the walls, one to each class of insets, one to the objects.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from rfir_core.errors import ConfigError, InputFileError, StageError

from .planes import Plane, connected_pieces, find_planes, footprint_areas_m2, votes_and_radii
from .insets import InsetSettings, find_insets
from .object_boxes import BoxSettings, box_fields, box_record, find_boxes, settings_errors
from .room_shell import ShellSettings, Surface, build_shell, surface_quads


@dataclass
class StructureSettings(ShellSettings, InsetSettings, BoxSettings):
    """[geom.structure] (configs/geom.toml): the shell's, the insets' and the object boxes' thresholds (their own
    dataclasses hold their defaults) and the plane search, object and tiling ones."""
    normal_deg: float = 25.0
    min_points: int = 40
    min_area_m2: float = 2.0
    piece_eps_m: float = 0.2
    max_planes: int = 60
    object_eps_m: float = 0.15
    object_min_points: int = 20
    spacing_m: float = 0.8
    tile_shell: bool = True
    keep_free: bool = True
    object_planes_only: bool = False
    insets: bool = True


@dataclass
class StructureResult:
    """What `run` wrote: the artifact's path, its surfaces, Gaussian counts (shell surfels written, photo
    Gaussians on the shell, in objects, free), object segments, wall-clock seconds, and the scale check
    (known, measured [m], or None), the object boxes (object_boxes.Box; none with objects = "keep")."""
    path: Path
    surfaces: list[Surface]
    num_in: int
    num_shell_surfels: int
    num_on_shell: int
    num_in_objects: int
    num_free: int
    num_objects: int
    num_object_planes: int
    seconds: float
    scale: tuple[str, str, float, float] | None = None
    warnings: list[str] = field(default_factory=list)
    boxes: list = field(default_factory=list)


def settings_from(table: dict) -> StructureSettings:
    """StructureSettings from the [geom.structure] table; unknown keys are refused."""
    known = {f.name for f in fields(StructureSettings)}
    unknown = sorted(set(table) - known)
    if unknown:
        raise ConfigError(f"geom.structure: unknown key(s) {', '.join(unknown)}")
    s = StructureSettings(**table)
    for name in ("distance_m", "cell_m", "spacing_m", "piece_eps_m", "object_eps_m", "inset_cell_m", "inset_depth_m",
                 "inset_spread"):
        if not getattr(s, name) > 0:
            raise ConfigError(f"geom.structure.{name} must be positive, got {getattr(s, name)}")
    errors = settings_errors(s)
    if errors:
        raise ConfigError(errors[0])
    return s


def parse_known_distance(text: str) -> tuple[str, str, float]:
    """'A:B=METRES' -> (surface A, surface B, distance [m])."""
    try:
        pair, value = text.split("=")
        a, b = pair.split(":")
        metres = float(value)
    except ValueError:
        raise ConfigError(f"--known-distance {text!r}: expected SURFACE:SURFACE=METRES, e.g. floor:ceiling=3.0") from None
    if not metres > 0:
        raise ConfigError(f"--known-distance {text!r}: the distance must be positive")
    return a.strip(), b.strip(), metres


def run(scene_path: str | Path, out_path: str | Path, table: dict, *, seed: int = 0, progress=None,
        known_distance: str | None = None) -> StructureResult:
    """Find the structure of the scene artifact at scene_path and write it to out_path (module docstring)."""
    from rfir_core.artifacts import read_artifact, write_artifact
    from rfir_core.progress import NullProgress
    from rfir_core.provenance import Provenance

    progress = progress or NullProgress()
    settings = settings_from(table)
    known = parse_known_distance(known_distance) if known_distance else None
    t0 = time.time()
    art = read_artifact(scene_path, "scene")
    x = np.asarray(art.data["gaussians/means"], float)
    normals = np.asarray(art.data["gaussians/normals"], float)
    if not (np.isfinite(x).all() and np.isfinite(normals).all()):
        raise InputFileError("non-finite Gaussian means or normals", path=scene_path)
    if len(x) < 10 * settings.min_points:
        raise InputFileError(f"{len(x)} Gaussians: too few for a room's planes (at least {10 * settings.min_points})",
                             path=scene_path)
    length = np.linalg.norm(normals, axis=1)
    if (length < 1e-9).any():
        raise InputFileError(f"{int((length < 1e-9).sum())} Gaussians have a zero normal", path=scene_path)
    normals = normals / length[:, None]

    with progress.task("structure: planes", total=settings.max_planes) as task:
        areas = footprint_areas_m2(art.data["gaussians/log_scales"])    # votes by area: any Gaussians (planes.py)
        planes = find_planes(x, normals, distance_m=settings.distance_m, normal_deg=settings.normal_deg,
                             min_points=settings.min_points, piece_eps_m=settings.piece_eps_m,
                             areas_m2=areas, min_area_m2=settings.min_area_m2,
                             max_planes=settings.max_planes, seed=seed, progress=task)
    try:
        surfaces = build_shell(x, planes, settings, areas)
    except ValueError as exc:
        raise StageError(f"{scene_path}: no room shell in {len(planes)} planes: {exc}") from None

    colors = art.data.get("gaussians/colors")
    if colors is not None and np.asarray(colors).shape[1] == 3 and settings.insets:
        inset_settings = InsetSettings(**{f.name: getattr(settings, f.name) for f in fields(InsetSettings)})
        insets = find_insets(x, normals, np.asarray(colors, float), list(surfaces), inset_settings)
        surfaces += insets
        # each inset class becomes a material of its own in rf-fit: say how many, also when none
        classes = sorted({s.name.rsplit("_", 1)[0] for s in insets})
        progress.log(f"insets (parts of a surface of another colour or depth): {len(insets)} in {len(classes)} "
                     f"class(es){': ' + ', '.join(classes) if classes else ''} (geom.structure.insets)")
    else:
        progress.log("insets: none searched (" + ("geom.structure.insets = false" if not settings.insets else
                                                  "the Gaussians carry no colours") + ")")
    on_shell, behind = _shell_sides(x, surfaces, settings.distance_m)
    inside = ~on_shell & ~behind
    piece = np.full(len(x), -1)
    piece[inside] = connected_pieces(x[inside], settings.object_eps_m, settings.object_min_points)
    in_object = piece >= 0
    boxes = []
    if settings.objects == "boxes":      # the segments as boxes (object_boxes.py); what no box explains is free
        votes, radii = votes_and_radii(areas, len(x))
        floor = next(s for s in surfaces if s.kind == "floor")
        boxes = find_boxes(x, normals, votes, radii / np.sqrt(2.0), piece, float(floor.offset * np.sign(floor.normal[2])),
                           [s.normal for s in surfaces if s.kind == "wall"], settings, distance_m=settings.distance_m,
                           normal_deg=settings.normal_deg, min_points=settings.object_min_points)
        in_object = np.zeros(len(x), bool)
        for b in boxes:
            in_object[b.members] = True
        object_planes = []
    else:
        shell_planes = {id(p) for p in planes if _used_by_shell(p, on_shell)}
        object_planes = [_levelled(p, x, settings.snap_deg) for p in planes
                         if id(p) not in shell_planes and in_object[p.members].mean() > 0.5]

    if settings.tile_shell:
        fields_out, names = _shell_fields(surfaces, settings.spacing_m, art.data.get("gaussians/colors"))
    else:
        fields_out, names = _shell_projected(art.data, x, on_shell, surfaces)
    num_segments = len(np.unique(piece[piece >= 0]))
    if settings.objects == "boxes":
        dropped = 0
        if settings.tile_shell:
            objects, dropped = box_fields(boxes, [s for s in surfaces if s.kind != "inset"], settings.spacing_m,
                                          settings.box_cells, settings.distance_m, len(names),
                                          None if colors is None else np.asarray(colors, float))
            objects = objects or {k: v[:0] for k, v in fields_out.items()}
        else:       # as the shell: the boxes' own Gaussians projected onto their nearest faces
            objects = _box_projected(art.data, x, boxes, in_object, first_label=len(names))
        names += [b.name for b in boxes]
        _log_boxes(progress, boxes, piece, in_object, dropped)
        num_objects = len(boxes)
    else:
        objects = _object_fields(art.data, piece, in_object, object_planes, first_label=len(names))
        names += [f"object_{k:02d}" for k in range(num_segments)]
        num_objects = num_segments
    if settings.object_planes_only and settings.objects == "keep":     # the objects as their planar parts alone
        on_plane = np.zeros(len(x), bool)
        for p in object_planes:
            on_plane[p.members] = True
        objects = {k: v[on_plane[in_object]] for k, v in objects.items()}
    free = _subset(art.data, (~on_shell & ~in_object) if settings.keep_free else np.zeros(len(x), bool), label=-1)
    # the fields every part has (box surfels carry no fields of photo Gaussians beyond a tiling's and colours)
    out = {k: np.concatenate([fields_out[k], objects[k], free[k]]) for k in fields_out if k in objects}

    warnings = [f"{s.name} is {s.tilt_deg:.2f} deg from {'vertical' if s.kind == 'wall' else 'horizontal'} "
                f"(over 1 deg: is the frame's z up?)" for s in surfaces
                if s.kind != "inset" and np.isfinite(s.tilt_deg) and s.tilt_deg > 1.0]
    scale = None
    if known is not None:
        measured = surface_distance(surfaces, known[0], known[1])
        scale = (known[0], known[1], known[2], measured)
    prov = Provenance(stage="geom.structure")
    prov.add_input(scene_path)
    prov.wall_time_s = time.time() - t0
    prov.extra = {"surfaces": [surface_record(s) for s in surfaces], "free_gaussians": int((~on_shell & ~in_object).sum()),
                  "object_segments": num_segments, "object_boxes": [box_record(b) for b in boxes],
                  "settings": {f.name: getattr(settings, f.name) for f in fields(settings)}}
    attrs = {"source": str(scene_path), "label_names": np.asarray(names, dtype=object)}
    path = write_artifact(out_path, "scene", out, attrs=attrs, provenance=prov)
    return StructureResult(Path(path), surfaces, len(x), len(fields_out["gaussians/means"]), int(on_shell.sum()),
                           int(in_object.sum()), int((~on_shell & ~in_object).sum()), num_objects, len(object_planes),
                           time.time() - t0, scale, warnings, boxes)


def _log_boxes(progress, boxes, piece: np.ndarray, in_box: np.ndarray, dropped: int) -> None:
    """Say how many boxes the object segments (piece [N], -1: none) gave, their sizes, and what was left free
    (in_box [N] bool: explained by a box)."""
    segments = np.unique(piece[piece >= 0])
    left = (piece >= 0) & ~in_box
    none = [k for k in segments if not in_box[piece == k].any()]
    sizes = ", ".join(f"{b.size_m[0]:.2f}x{b.size_m[1]:.2f}x{b.size_m[2]:.2f}" for b in boxes)
    progress.log(f"objects as boxes: {len(boxes)} from {len(segments)} segment(s)"
                 f"{' (u x v x height [m]: ' + sizes + ')' if boxes else ''}, {dropped} face(s) on the shell left out; "
                 f"left free: {int(left.sum())} of their {int((piece >= 0).sum())} Gaussians, {len(none)} segment(s) with "
                 f"no box (geom.structure.objects)")


def surface_record(s: Surface) -> dict:
    """A surface's summary for provenance and the command's table (angles in degrees, lengths in metres)."""
    return {"name": s.name, "kind": s.kind, "normal": [round(float(v), 5) for v in s.normal],
            "offset_m": round(s.offset, 4), "size_m": [round(v, 3) for v in s.size_m],
            "openings_m2": round(s.openings_m2, 3), "tilt_deg": None if not np.isfinite(s.tilt_deg) else round(s.tilt_deg, 3),
            "gaussians": int(len(s.members)), "inferred": s.inferred}


def surface_distance(surfaces: list[Surface], a: str, b: str) -> float:
    """Distance [m] from the centre of surface a's extent to the plane of surface b."""
    named = {s.name: s for s in surfaces}
    for name in (a, b):
        if name not in named:
            raise ConfigError(f"--known-distance: no surface {name!r}; the surfaces are {', '.join(named)}")
    sa, sb = named[a], named[b]
    w, h = sa.size_m
    centre = sa.origin + 0.5 * w * sa.u + 0.5 * h * sa.v
    return float(abs(centre @ sb.normal - sb.offset))


def _levelled(plane: Plane, x: np.ndarray, snap_deg: float) -> Plane:
    """The plane made exactly level or plumb when within snap_deg of it (a desk top, a cupboard's side: in a frame
    with z up, as the shell's planes), its offset the members' median; else the plane as fitted."""
    up = abs(plane.normal[2])
    if up >= np.cos(np.radians(snap_deg)):
        normal = np.array([0.0, 0.0, 1.0])
    elif up <= np.sin(np.radians(snap_deg)):
        normal = plane.normal * np.array([1.0, 1.0, 0.0])
        normal /= np.linalg.norm(normal)
    else:
        return plane
    offset = float(np.median(x[plane.members] @ normal))
    return Plane(normal, offset, plane.members, float(np.sqrt(np.mean((x[plane.members] @ normal - offset) ** 2))))


def _used_by_shell(plane: Plane, on_shell: np.ndarray) -> bool:
    return bool(on_shell[plane.members].mean() > 0.5)


def _shell_sides(x: np.ndarray, surfaces: list[Surface], distance_m: float) -> tuple[np.ndarray, np.ndarray]:
    """([N] bool on a shell surface: within distance_m of its plane inside its extent, [N] bool behind one: farther
    than distance_m on its outer side, inside its extent)."""
    on, behind = np.zeros(len(x), bool), np.zeros(len(x), bool)
    for s in surfaces:
        d = x @ s.normal - s.offset
        rel = x - s.origin
        w, h = s.size_m
        a, b = rel @ s.u, rel @ s.v
        within = (a >= -distance_m) & (a <= w + distance_m) & (b >= -distance_m) & (b <= h + distance_m)
        on |= within & (np.abs(d) <= distance_m)
        behind |= within & (d < -distance_m)
    on[np.concatenate([s.members for s in surfaces])] = True
    return on, behind & ~on


def _shell_fields(surfaces: list[Surface], spacing_m: float, colors) -> tuple[dict, list[str]]:
    """Surfels tiling the shell's extents (labels = index into the returned names) and the surfaces' names."""
    from .from_mesh import gaussians_from_mesh

    verts, faces, labels, off = [], [], [], 0
    for k, s in enumerate(surfaces):
        v, f = surface_quads(s)
        verts.append(v)
        faces.append(f + off)
        labels.append(np.full(len(f), k))
        off += len(v)
    out = gaussians_from_mesh(np.concatenate(verts), np.concatenate(faces), spacing_m, labels=np.concatenate(labels),
                              rectangles=True)
    if colors is not None:
        colors = np.asarray(colors, float)
        fallback = np.median(colors, axis=0)
        per = np.array([np.median(colors[s.members], axis=0) if len(s.members) else fallback for s in surfaces])
        out["gaussians/colors"] = per[out["gaussians/labels"]]
    return out, [s.name for s in surfaces]


def _shell_projected(data: dict, x: np.ndarray, on_shell: np.ndarray, surfaces: list[Surface]) -> tuple[dict, list[str]]:
    """The shell's own Gaussians (on_shell [N] bool) projected onto their surface (the nearest plane; an inset's
    where its cells are), labelled with the surface's index into the returned names: the shell without tiling
    (tile_shell = false; an inferred ceiling then has no Gaussians)."""
    idx = np.flatnonzero(on_shell)
    dist = np.stack([np.abs(x[idx] @ s.normal - s.offset) for s in surfaces], 1)
    for k, s in enumerate(surfaces):
        if s.kind == "inset":       # an inset's cells are its own, its wall's are not
            rel = x[idx] - s.origin
            i = np.clip(np.floor(rel @ s.u / s.cell_m).astype(int), 0, s.occupied.shape[0] - 1)
            j = np.clip(np.floor(rel @ s.v / s.cell_m).astype(int), 0, s.occupied.shape[1] - 1)
            dist[:, k] = np.where(s.occupied[i, j], -1.0, np.inf)
    which = np.argmin(dist, axis=1)
    planes = [Plane(s.normal, s.offset, idx[which == k], 0.0) for k, s in enumerate(surfaces)]
    labels = np.full(len(x), -1)
    labels[idx] = which
    return _projected(data, on_shell, labels, planes), [s.name for s in surfaces]


def _box_projected(data: dict, x: np.ndarray, boxes: list, in_box: np.ndarray, first_label: int) -> dict:
    """The fields of the boxes' Gaussians (in_box [N] bool), each projected onto its box's nearest face and labelled
    first_label + the box's index (tile_shell = false)."""
    labels = np.full(len(x), -1)
    planes = []
    for k, box in enumerate(boxes):
        labels[box.members] = first_label + k
        axes, half = box.axes, 0.5 * box.size_m
        local = (x[box.members] - box.centre) @ axes.T                     # [M, 3] in the box's frame
        axis = np.argmin(np.abs(np.abs(local) - half), axis=1)              # the nearest face's axis ...
        side = np.sign(local[np.arange(len(local)), axis])                  # ... and side
        side[side == 0] = 1.0
        for a in range(3):
            for sign in (-1.0, 1.0):
                normal = sign * axes[a]
                planes.append(Plane(normal, float(normal @ box.centre + half[a]),
                                    box.members[(axis == a) & (side == sign)], 0.0))
    return _projected(data, in_box, labels, planes)


def _subset(data: dict, keep: np.ndarray, label) -> dict:
    """The scene fields of the Gaussians keep [N] bool, labelled `label` (an int or an [N] array)."""
    out = {k: np.asarray(v)[keep] for k, v in data.items() if k.startswith("gaussians/") and k != "gaussians/labels"}
    out["gaussians/labels"] = (np.full(len(keep), label) if np.isscalar(label) else np.asarray(label))[keep].astype(np.int64)
    return out


def _object_fields(data: dict, piece: np.ndarray, in_object: np.ndarray, planes: list[Plane], first_label: int) -> dict:
    """The object segments' Gaussians (labels first_label + segment), those on one of `planes` projected onto it:
    mean moved onto the plane, normal the plane's, covariance flattened into it (thickness 5 % of the smaller
    in-plane spread, as mesh surfels)."""
    uniq, seg = np.unique(piece[in_object], return_inverse=True)
    labels = np.full(len(piece), -1)
    labels[in_object] = first_label + seg
    return _projected(data, in_object, labels, [Plane(p.normal, p.offset, p.members[in_object[p.members]], p.rms_m)
                                                 for p in planes])


def _projected(data: dict, keep: np.ndarray, labels: np.ndarray, planes: list[Plane]) -> dict:
    """The fields of the Gaussians keep [N] bool with labels [N], each plane's members projected onto it."""
    x = np.asarray(data["gaussians/means"], float).copy()
    normals = np.asarray(data["gaussians/normals"], float).copy()
    log_scales = np.asarray(data["gaussians/log_scales"], float).copy()
    rotations = np.asarray(data["gaussians/rotations"], float).copy()
    for p in planes:
        idx = p.members
        if len(idx) == 0:
            continue
        x[idx] -= np.outer(x[idx] @ p.normal - p.offset, p.normal)
        sign = np.where(normals[idx] @ p.normal < 0, -1.0, 1.0)
        normals[idx] = sign[:, None] * p.normal
        log_scales[idx], rotations[idx] = _flattened(log_scales[idx], rotations[idx], normals[idx])
    data = {**data, "gaussians/means": x, "gaussians/normals": normals, "gaussians/log_scales": log_scales,
            "gaussians/rotations": rotations}
    return _subset(data, keep, labels)


def _flattened(log_scales: np.ndarray, rotations: np.ndarray, normals: np.ndarray):
    """(log_scales [n, 3], rotations [n, 4] wxyz) of the Gaussians' covariances projected into the planes of normals
    [n, 3]: in-plane axes and spreads from the projected covariance, the third axis the normal."""
    from .from_mesh import _quat_from_matrix

    w, xq, yq, zq = rotations.T
    r = np.stack([np.stack([1 - 2 * (yq ** 2 + zq ** 2), 2 * (xq * yq - w * zq), 2 * (xq * zq + w * yq)], -1),
                  np.stack([2 * (xq * yq + w * zq), 1 - 2 * (xq ** 2 + zq ** 2), 2 * (yq * zq - w * xq)], -1),
                  np.stack([2 * (xq * zq - w * yq), 2 * (yq * zq + w * xq), 1 - 2 * (xq ** 2 + yq ** 2)], -1)], 1)
    cov = np.einsum("nij,nj,nkj->nik", r, np.exp(2 * log_scales), r)
    ref = np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    t1 = np.cross(normals, ref)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    t2 = np.cross(normals, t1)
    basis = np.stack([t1, t2], -1)                                   # [n, 3, 2]
    c2 = np.einsum("nia,nij,njb->nab", basis, cov, basis)
    ev, evec = np.linalg.eigh(c2)                                    # ascending
    e1 = np.einsum("nia,na->ni", basis, evec[:, :, 1])
    e2 = np.cross(normals, e1)
    s1, s2 = np.sqrt(np.maximum(ev[:, 1], 1e-12)), np.sqrt(np.maximum(ev[:, 0], 1e-12))
    rot = np.stack([e1, e2, normals], -1)
    return np.log(np.stack([s1, s2, 0.05 * s2], 1)), _quat_from_matrix(rot)
