"""Edited ground-truth scenes: the independent simulator's side of issue 9's validation.

`rfir edit` changes the fitted Gaussians; to check it, the simulator must produce the same change
in the meshes it simulates. An edit here is one string, `NAMES:OP`:

    desk_0[0369]|chair_0[0369]:translate:0,1,0    move the front desk row (and its chairs) 1 m in +y
    whiteboard:delete                              remove an object
    wall_back:material:metal                       swap the radio material (an ITU name)
    brick_07:rotate:0,0,1,30,0.1,0.0,0.2           rotate 30 deg about the axis (0,0,1) through the point

NAMES is one or more object names or shell patterns separated by "|"; angles in degrees, lengths in
metres, world frame (the frame of the scene's ground-truth meshes and therefore of a fit made from
them). A rotation without a pivot turns about the centroid of the selected objects' vertices.
The edits are applied in order after the scene is built, and recorded in the measurements'
`simulator` attributes.
"""
from __future__ import annotations

import fnmatch

import numpy as np

from rfir_core.errors import ConfigError

from .scenes import SceneSpec

OPS = ("translate", "rotate", "delete", "material")
# Sionna RT's ITU radio materials (itu-radio-material "type").
ITU_MATERIALS = ("concrete", "brick", "plasterboard", "wood", "glass", "ceiling_board", "chipboard", "plywood",
                 "marble", "floorboard", "metal", "very_dry_ground", "medium_dry_ground", "wet_ground")


def _floats(text: str, counts: tuple[int, ...], edit: str) -> np.ndarray:
    try:
        vals = np.array([float(v) for v in text.split(",")], np.float64)
    except ValueError:
        vals = np.zeros(0)
    if len(vals) not in counts or not np.all(np.isfinite(vals)):
        raise ConfigError(f"simulate.scene_edits {edit!r}: expected {' or '.join(map(str, counts))} numbers")
    return vals


def rotation_matrix(axis, angle_deg: float) -> np.ndarray:
    """[3, 3] rotation by angle_deg about the unit vector along axis (right-handed)."""
    a = np.asarray(axis, np.float64)
    a = a / np.linalg.norm(a)
    t = np.radians(angle_deg)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * (k @ k)


# how the simulator records the edits in a measurements file's `simulator` attribute `scene_edits`
RECORD_SEPARATOR = "; "


def measurement_scene_edits(meas) -> list[str]:
    """The scene edits a measurements artifact was simulated with, in order; [] when it has none."""
    text = str((meas.free.get("simulator@attrs") or {}).get("scene_edits", ""))
    return [e.strip() for e in text.split(RECORD_SEPARATOR) if e.strip()]


def apply_scene_edits(spec: SceneSpec, edits: list[str]) -> SceneSpec:
    """Apply `edits` (strings, module docstring) to spec in place and return it.

    ConfigError naming the edit for an unknown operation, bad numbers, a zero rotation axis or names
    that match no object. Labels are renumbered after a delete so they stay indices into spec.objects."""
    for edit in edits:
        names, _, rest = str(edit).partition(":")
        op, _, args = rest.partition(":")
        if op not in OPS:
            raise ConfigError(f"simulate.scene_edits {edit!r}: unknown operation {op!r} (known: {', '.join(OPS)})")
        patterns = [p.strip() for p in names.split("|") if p.strip()]
        chosen = [o for o in spec.objects if any(fnmatch.fnmatchcase(o.name, p) for p in patterns)]
        if not chosen:
            raise ConfigError(f"simulate.scene_edits {edit!r}: no object of scene {spec.name!r} matches {names!r}")
        if op == "delete":
            spec.objects = [o for o in spec.objects if o not in chosen]
            for i, o in enumerate(spec.objects):
                o.label = i
        elif op == "material":
            if args not in ITU_MATERIALS:
                raise ConfigError(f"simulate.scene_edits {edit!r}: unknown radio material {args!r} "
                                  f"(known: {', '.join(ITU_MATERIALS)})")
            for o in chosen:
                o.radio_material = args
        elif op == "translate":
            d = _floats(args, (3,), edit)
            for o in chosen:
                o.vertices = o.vertices + d
        else:
            v = _floats(args, (4, 7), edit)
            if np.linalg.norm(v[:3]) == 0:
                raise ConfigError(f"simulate.scene_edits {edit!r}: the rotation axis is zero")
            pivot = v[4:] if len(v) == 7 else np.concatenate([o.vertices for o in chosen]).mean(0)
            rot = rotation_matrix(v[:3], v[3])
            for o in chosen:
                o.vertices = (o.vertices - pivot) @ rot.T + pivot
    return spec
