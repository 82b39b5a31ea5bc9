"""Ground-truth scenes, shared by the radio simulator and the photo renderer.

Every scene is built by code from boxes (and, for `car`, Sionna's low-poly car mesh), so the same
meshes drive both the visual version (textures, Mitsuba) and the radio version (ITU materials,
Sionna RT). World frame: right-handed, z up, metres.

Mesh conventions
- Each box face has its own 4 vertices (no vertex is shared between faces), so a renderer that
  interpolates vertex normals still shades boxes flat, and face normals are exact for Sionna.
- Faces wind counter-clockwise seen from outside (normal = (v1 - v0) x (v2 - v0) points out).
  The room shell (walls, floor, ceiling) is made of single-sided rectangles whose normals point
  into the room, toward every camera and antenna inside it.
- Objects for RCS sit centred at the origin: the turntable axis is +z through the origin, and the
  object's bounding box is centred on (0, 0, 0).
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOM_SCENES = ("classroom", "flat", "office", "empty")
OBJECT_SCENES = ("lego", "car", "h-target", "plate", "trio")
SCENES = ROOM_SCENES + OBJECT_SCENES


@dataclass
class SceneObject:
    """One labelled mesh with a radio material and a visual appearance."""

    name: str  # unique within the scene, e.g. "desk_03"
    label: int  # object label id (>= 0), index into SceneSpec.objects
    vertices: np.ndarray  # (V, 3) float64, metres, world frame, z up
    faces: np.ndarray  # (F, 3) int32, counter-clockwise seen from outside
    radio_material: str  # ITU material name for Sionna ("concrete", "metal", ...)
    visual: str  # procedural texture name ("wood", "brick", "plaster", ...)
    color: tuple  # base RGB in [0, 1]
    thickness_m: float = 0.1  # slab thickness Sionna uses for reflection/transmission

    def face_normals(self) -> np.ndarray:
        """Unit normals (F, 3) from the winding."""
        v = self.vertices[self.faces]
        n = np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0])
        return n / np.linalg.norm(n, axis=1, keepdims=True)

    def area_m2(self) -> float:
        v = self.vertices[self.faces]
        return float(0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1).sum())


@dataclass
class SceneSpec:
    """A scene: labelled objects plus bounds. kind is "room" or "object" (turntable in free space)."""

    name: str
    kind: str
    objects: list[SceneObject]
    bounds: np.ndarray  # (2, 3) min/max, metres
    info: dict = field(default_factory=dict)  # free-form facts (room size, object height, ...)

    @property
    def num_faces(self) -> int:
        return int(sum(len(o.faces) for o in self.objects))

    def label_names(self) -> list[str]:
        return [o.name for o in self.objects]


# --------------------------------------------------------------------------------------------
# mesh helpers
# --------------------------------------------------------------------------------------------
def _quad(p0, p1, p2, p3) -> tuple[np.ndarray, np.ndarray]:
    """A rectangle from 4 corners in counter-clockwise order seen from the front."""
    v = np.array([p0, p1, p2, p3], dtype=np.float64)
    return v, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.int32)


def _merge(parts) -> tuple[np.ndarray, np.ndarray]:
    vs, fs, off = [], [], 0
    for v, f in parts:
        vs.append(v)
        fs.append(f + off)
        off += len(v)
    return np.concatenate(vs), np.concatenate(fs).astype(np.int32)


def box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box from corner lo to corner hi: 24 vertices, 12 outward triangles."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    return _merge([
        _quad((x0, y0, z0), (x0, y1, z0), (x1, y1, z0), (x1, y0, z0)),  # -z
        _quad((x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)),  # +z
        _quad((x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1)),  # -y
        _quad((x0, y1, z0), (x0, y1, z1), (x1, y1, z1), (x1, y1, z0)),  # +y
        _quad((x0, y0, z0), (x0, y0, z1), (x0, y1, z1), (x0, y1, z0)),  # -x
        _quad((x1, y0, z0), (x1, y1, z0), (x1, y1, z1), (x1, y0, z1)),  # +x
    ])


def boxes(list_lo_hi) -> tuple[np.ndarray, np.ndarray]:
    return _merge([box(lo, hi) for lo, hi in list_lo_hi])


def rect_xy(x0, x1, y0, y1, z, up: bool) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal rectangle at height z, normal +z if up else -z."""
    if up:
        return _quad((x0, y0, z), (x1, y0, z), (x1, y1, z), (x0, y1, z))
    return _quad((x0, y0, z), (x0, y1, z), (x1, y1, z), (x1, y0, z))


def wall(origin, u_dir, normal, length: float, height: float, openings=()) -> tuple[np.ndarray, np.ndarray]:
    """A vertical wall rectangle with rectangular holes.

    origin: bottom corner (3,); u_dir: unit horizontal direction along the wall; normal: unit
    normal the faces point to. openings: (u0, u1, z0, z1) in wall coordinates (metres from
    origin along u_dir, height above origin). The wall is split on a grid through the opening
    edges and the cells inside an opening are dropped.
    """
    origin, u_dir, normal = (np.asarray(a, dtype=np.float64) for a in (origin, u_dir, normal))
    up = np.array([0.0, 0.0, 1.0])
    us = sorted({0.0, length, *[o[0] for o in openings], *[o[1] for o in openings]})
    zs = sorted({0.0, height, *[o[2] for o in openings], *[o[3] for o in openings]})
    flip = np.dot(np.cross(u_dir, up), normal) < 0  # winding u->up gives normal u x up
    parts = []
    for ua, ub in zip(us[:-1], us[1:]):
        for za, zb in zip(zs[:-1], zs[1:]):
            uc, zc = 0.5 * (ua + ub), 0.5 * (za + zb)
            if any(o[0] <= uc <= o[1] and o[2] <= zc <= o[3] for o in openings):
                continue
            p = [origin + ua * u_dir + za * up, origin + ub * u_dir + za * up,
                 origin + ub * u_dir + zb * up, origin + ua * u_dir + zb * up]
            parts.append(_quad(*(p[::-1] if flip else p)))
    return _merge(parts)


def rotate_z(v: np.ndarray, angle_rad: float) -> np.ndarray:
    c, s = np.cos(angle_rad), np.sin(angle_rad)
    return v @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T


class _Builder:
    def __init__(self):
        self.objects: list[SceneObject] = []

    def add(self, name, mesh, radio, visual, color, thickness_m=0.1):
        v, f = mesh
        self.objects.append(SceneObject(name, len(self.objects), np.asarray(v, np.float64),
                                        np.asarray(f, np.int32), radio, visual, tuple(color),
                                        float(thickness_m)))


def _bounds(objects) -> np.ndarray:
    allv = np.concatenate([o.vertices for o in objects])
    return np.stack([allv.min(0), allv.max(0)])


def _centre_objects(objects) -> None:
    """Move objects so that the bounding box of their union is centred on the origin."""
    b = _bounds(objects)
    c = 0.5 * (b[0] + b[1])
    for o in objects:
        o.vertices = o.vertices - c


# --------------------------------------------------------------------------------------------
# scenes
# --------------------------------------------------------------------------------------------
CLASSROOM_SIZE_M = (9.0, 7.0, 3.0)


def _desk(x, y, w=1.2, d=0.6, h=0.75, top=0.03, leg=0.04):
    """Desk centred at (x, y) on the floor: a top and four legs."""
    x0, x1, y0, y1 = x - w / 2, x + w / 2, y - d / 2, y + d / 2
    parts = [((x0, y0, h - top), (x1, y1, h))]
    for lx in (x0 + 0.02, x1 - 0.02 - leg):
        for ly in (y0 + 0.02, y1 - 0.02 - leg):
            parts.append(((lx, ly, 0.0), (lx + leg, ly + leg, h - top)))
    return boxes(parts)


def _chair(x, y, facing: float, s=0.42, h=0.45, back=0.85, leg=0.03):
    """Chair centred at (x, y); the sitter faces direction `facing` (rad about +z)."""
    r = s / 2
    parts = [((-r, -r, h - 0.03), (r, r, h)),  # seat
             ((r - 0.03, -r, h), (r, r, back))]  # backrest behind the sitter (+x before rotation)
    for lx in (-r, r - leg):
        for ly in (-r, r - leg):
            parts.append(((lx, ly, 0.0), (lx + leg, ly + leg, h - 0.03)))
    v, f = boxes(parts)
    # before rotation the sitter faces -x; rotate so they face `facing`
    v = rotate_z(v, facing - np.pi) + np.array([x, y, 0.0])
    return v, f


def classroom() -> SceneSpec:
    """About 9 x 7 x 3 m: front (whiteboard) at x = 0, windows on y = 0, door on y = 7."""
    lx, ly, lz = CLASSROOM_SIZE_M
    b = _Builder()
    windows = [(1.5, 3.0, 0.9, 2.3), (4.0, 5.5, 0.9, 2.3), (6.5, 8.0, 0.9, 2.3)]
    door = (0.8, 1.8, 0.0, 2.1)  # along the y = 7 wall, measured from x = 0
    b.add("floor", rect_xy(0, lx, 0, ly, 0.0, up=True), "concrete", "tiles", (0.55, 0.52, 0.48), 0.2)
    b.add("ceiling", rect_xy(0, lx, 0, ly, lz, up=False), "concrete", "plaster", (0.92, 0.91, 0.88), 0.2)
    b.add("wall_front", wall((0, 0, 0), (0, 1, 0), (1, 0, 0), ly, lz), "concrete", "plaster", (0.85, 0.83, 0.78), 0.2)
    b.add("wall_back", wall((lx, 0, 0), (0, 1, 0), (-1, 0, 0), ly, lz), "concrete", "brick", (0.62, 0.33, 0.25), 0.2)
    b.add("wall_windows", wall((0, 0, 0), (1, 0, 0), (0, 1, 0), lx, lz, windows), "concrete", "plaster",
          (0.80, 0.82, 0.76), 0.2)
    b.add("wall_door", wall((0, ly, 0), (1, 0, 0), (0, -1, 0), lx, lz, [door]), "concrete", "plaster",
          (0.78, 0.80, 0.84), 0.2)
    for i, (u0, u1, z0, z1) in enumerate(windows):
        # pane facing into the room; the opening in the wall leaves the outside as free space
        b.add(f"window_{i:02d}", wall((u0, 0.0, z0), (1, 0, 0), (0, 1, 0), u1 - u0, z1 - z0), "glass", "glass",
              (0.70, 0.82, 0.88), 0.006)
    b.add("door", wall((door[0], ly, 0.0), (1, 0, 0), (0, -1, 0), door[1] - door[0], door[3]), "wood", "wood",
          (0.55, 0.36, 0.20), 0.04)
    b.add("whiteboard", box((0.0, 1.9, 0.9), (0.02, 5.1, 2.1)), "metal", "metal", (0.93, 0.94, 0.95), 0.002)
    b.add("teacher_desk", boxes([((0.9, 2.6, 0.0), (1.6, 4.4, 0.76))]), "wood", "wood", (0.45, 0.30, 0.18), 0.03)
    b.add("teacher_chair", _chair(0.55, 3.5, facing=0.0), "wood", "plastic", (0.15, 0.20, 0.45), 0.02)
    k = 0
    for x in (3.0, 4.5, 6.0, 7.5):
        for col, y in enumerate((1.4, 3.5, 5.6)):
            b.add(f"desk_{k:02d}", _desk(x, y), "wood", "wood", (0.62, 0.45, 0.28), 0.03)
            b.add(f"chair_{k:02d}", _chair(x + 0.55, y, facing=np.pi), "wood", "plastic",
                  ((0.7, 0.2, 0.15), (0.2, 0.45, 0.25), (0.2, 0.3, 0.6))[col], 0.02)
            k += 1
    return SceneSpec("classroom", "room", b.objects, np.array([[0.0, 0.0, 0.0], [lx, ly, lz]]),
                     info={"size_m": [lx, ly, lz]})


FLAT_SIZE_M = (9.0, 7.0, 2.7)
# Rooms of the flat as (x0, x1, y0, y1) boxes in metres (the partitions run along their edges).
FLAT_ROOMS = {"living": (0.0, 5.0, 0.0, 4.2), "kitchen": (0.0, 5.0, 4.2, 7.0),
              "bedroom": (5.0, 9.0, 0.0, 3.8), "study": (5.0, 9.0, 3.8, 7.0)}


def _sofa(x0, y0, w=2.0, d=0.9, seat=0.45, back=0.85, arm=0.2):
    """Sofa with its back along y = y0 + d (the sitter faces -y): seat block, backrest and two arms."""
    return boxes([((x0, y0, 0.0), (x0 + w, y0 + d, seat)),
                  ((x0, y0 + d - 0.2, seat), (x0 + w, y0 + d, back)),
                  ((x0, y0, seat), (x0 + arm, y0 + d - 0.2, 0.65)),
                  ((x0 + w - arm, y0, seat), (x0 + w, y0 + d - 0.2, 0.65))])


def flat() -> SceneSpec:
    """A furnished flat of 9 x 7 x 2.7 m: four rooms (FLAT_ROOMS) inside a concrete shell.

    A brick wall at x = 5 (two door openings) splits living room and kitchen (west) from bedroom
    and study (east); plasterboard partitions at y = 4.2 (west, one door opening) and y = 3.8 (east,
    none). Glass windows in the outer walls, a wooden entrance door, and furniture of wood,
    chipboard and metal (a fridge, kitchen units, a filing cabinet, a television). Interior walls are
    single two-sided rectangles with their slab thickness (as the classroom's shell);
    info["floorplan"] maps what a floor plan shows (shell, walls, windows, entrance door) to the names a
    plan gives them (no material); info["interior_walls"] are the walls a plan places less exactly.
    """
    lx, ly, lz = FLAT_SIZE_M
    b = _Builder()
    win_s = [(1.0, 2.6, 0.9, 2.2), (6.2, 7.8, 0.9, 2.2)]      # y = 0 wall (living, bedroom), along +x
    win_n = [(1.0, 2.5, 0.9, 2.2)]                            # y = 7 wall (study), along -x from x = 9
    win_w = [(0.7, 2.0, 0.9, 2.2)]                            # x = 0 wall (kitchen), along -y from y = 7
    entrance = (4.3, 5.2, 0.0, 2.05)                          # y = 7 wall, along -x from x = 9 (kitchen)
    grey = (0.86, 0.85, 0.82)
    b.add("floor", rect_xy(0, lx, 0, ly, 0.0, up=True), "concrete", "tiles", (0.55, 0.50, 0.45), 0.2)
    b.add("ceiling", rect_xy(0, lx, 0, ly, lz, up=False), "concrete", "plaster", (0.93, 0.92, 0.90), 0.2)
    b.add("outer_wall_south", wall((0, 0, 0), (1, 0, 0), (0, 1, 0), lx, lz, win_s), "concrete", "plaster", grey, 0.25)
    b.add("outer_wall_east", wall((lx, 0, 0), (0, 1, 0), (-1, 0, 0), ly, lz), "concrete", "plaster", grey, 0.25)
    b.add("outer_wall_north", wall((lx, ly, 0), (-1, 0, 0), (0, -1, 0), lx, lz, win_n + [entrance]), "concrete",
          "plaster", grey, 0.25)
    b.add("outer_wall_west", wall((0, ly, 0), (0, -1, 0), (1, 0, 0), ly, lz, win_w), "concrete", "plaster", grey, 0.25)
    panes = [((u0, 0.0, z0), (1, 0, 0), (0, 1, 0), u1 - u0, z1 - z0) for u0, u1, z0, z1 in win_s]
    panes += [((lx - u0, ly, z0), (-1, 0, 0), (0, -1, 0), u1 - u0, z1 - z0) for u0, u1, z0, z1 in win_n]
    panes += [((0.0, ly - u0, z0), (0, -1, 0), (1, 0, 0), u1 - u0, z1 - z0) for u0, u1, z0, z1 in win_w]
    for i, args in enumerate(panes):
        b.add(f"window_{i:02d}", wall(*args), "glass", "glass", (0.70, 0.82, 0.88), 0.006)
    b.add("entrance_door", wall((lx - entrance[0], ly, 0.0), (-1, 0, 0), (0, -1, 0), entrance[1] - entrance[0],
                                entrance[3]), "wood", "wood", (0.50, 0.33, 0.20), 0.04)
    # interior walls: brick x = 5 (doors living->bedroom, kitchen->study), plasterboard y = 4.2 and y = 3.8
    b.add("brick_wall", wall((5.0, 0, 0), (0, 1, 0), (-1, 0, 0), ly, lz, [(2.6, 3.5, 0.0, 2.05), (5.3, 6.2, 0.0, 2.05)]),
          "brick", "brick", (0.66, 0.36, 0.27), 0.12)
    b.add("partition_west", wall((0, 4.2, 0), (1, 0, 0), (0, -1, 0), 5.0, lz, [(3.6, 4.5, 0.0, 2.05)]),
          "plasterboard", "plaster", (0.90, 0.89, 0.84), 0.025)
    b.add("partition_east", wall((5.0, 3.8, 0), (1, 0, 0), (0, -1, 0), 4.0, lz), "plasterboard", "plaster",
          (0.88, 0.90, 0.86), 0.025)
    wood, dark = (0.60, 0.43, 0.27), (0.40, 0.27, 0.16)
    steel = (0.80, 0.81, 0.83)
    # living room (x 0..5, y 0..4.2)
    b.add("sofa", _sofa(0.6, 3.0), "chipboard", "fabric", (0.35, 0.40, 0.50), 0.02)
    b.add("coffee_table", _desk(1.6, 2.1, w=1.0, d=0.55, h=0.45), "wood", "wood", wood, 0.03)
    b.add("dining_table", _desk(3.6, 1.4, w=1.6, d=0.9), "wood", "wood", wood, 0.03)
    b.add("tv", box((1.0, 0.05, 0.8), (2.2, 0.12, 1.5)), "metal", "metal", (0.10, 0.10, 0.12), 0.002)
    # kitchen (x 0..5, y 4.2..7)
    b.add("fridge", box((0.05, 4.3, 0.0), (0.75, 5.0, 1.8)), "metal", "metal", steel, 0.002)
    b.add("kitchen_units", box((0.05, 5.0, 0.0), (0.65, 6.9, 0.9)), "metal", "metal", steel, 0.002)
    b.add("kitchen_table", _desk(2.6, 5.6, w=1.2, d=0.8), "wood", "wood", wood, 0.03)
    # bedroom (x 5..9, y 0..3.8)
    b.add("bed", box((6.8, 1.2, 0.0), (8.9, 2.8, 0.5)), "wood", "wood", dark, 0.03)
    b.add("wardrobe", box((5.1, 0.1, 0.0), (5.7, 1.9, 2.0)), "chipboard", "wood", (0.85, 0.80, 0.70), 0.02)
    # study (x 5..9, y 3.8..7)
    b.add("desk", _desk(7.6, 6.55, w=1.4, d=0.7), "wood", "wood", wood, 0.03)
    b.add("bookshelf", box((8.6, 4.0, 0.0), (8.95, 5.4, 1.9)), "wood", "wood", dark, 0.03)
    b.add("filing_cabinet", box((5.1, 6.4, 0.0), (5.6, 6.95, 1.1)), "metal", "metal", steel, 0.002)
    # what a floor plan shows, under the names a plan gives (no material named): true name -> plan name
    plan = {"floor": "floor", "ceiling": "ceiling",
            **{f"outer_wall_{k}": f"outer_wall_{i:02d}" for i, k in enumerate(("south", "east", "north", "west"))},
            **{f"window_{i:02d}": f"window_{i:02d}" for i in range(len(panes))}, "entrance_door": "door",
            "brick_wall": "thick_wall_00", "partition_west": "thin_wall_00", "partition_east": "thin_wall_01"}
    return SceneSpec("flat", "room", b.objects, np.array([[0.0, 0.0, 0.0], [lx, ly, lz]]),
                     info={"size_m": [lx, ly, lz], "rooms": {k: list(v) for k, v in FLAT_ROOMS.items()},
                           "floorplan": plan, "interior_walls": ["brick_wall", "partition_west", "partition_east"]})


OFFICE_SIZE_M = (10.0, 8.0, 3.0)
# The office's L-shaped floor as (x0, x1, y0, y1) boxes in metres: the main room along y = 0 (an open office
# and, behind the glass partition at x = OFFICE_GLASS_X_M, a meeting room) and a wing to the north-west; the
# north-east corner (x > 5.5, y > 4.5) is a concrete core outside the room.
OFFICE_AREAS = {"main": (0.0, 10.0, 0.0, 4.5), "wing": (0.0, 5.5, 4.5, 8.0)}
OFFICE_GLASS_X_M = 7.5


def _metal_shelving(x0, y0, x1, y1, h=2.0, shelves=4, post=0.04, board=0.02):
    """Open steel shelving on the floor over [x0, x1] x [y0, y1]: four corner posts and `shelves` boards."""
    parts = [((px, py, 0.0), (px + post, py + post, h)) for px in (x0, x1 - post) for py in (y0, y1 - post)]
    for k in range(shelves):
        z = 0.1 + k * (h - 0.15) / max(shelves - 1, 1)
        parts.append(((x0, y0, z - board), (x1, y1, z)))
    return boxes(parts)


def office() -> SceneSpec:
    """An L-shaped office of 10 x 8 x 3 m (OFFICE_AREAS) in a concrete shell, with a glass partition.

    The main room (x 0..10, y 0..4.5) holds an open office and, behind a floor-to-ceiling glass wall at
    x = OFFICE_GLASS_X_M with a door gap, a meeting room; the wing (x 0..5.5, y 4.5..8) holds more desks and
    the wooden entrance door (y = 8). The two walls of the inner corner are one object, "wall_core", whose
    bounding box covers the concrete core outside the room (so grids and cameras keep out of it). Glass
    windows in the outer walls; metal furniture: two filing cabinets, a tall cupboard and open shelving.
    """
    lx, ly, lz = OFFICE_SIZE_M
    mx0, mx1, my0, my1 = OFFICE_AREAS["main"]
    wx0, wx1, wy0, wy1 = OFFICE_AREAS["wing"]
    gx = OFFICE_GLASS_X_M
    b = _Builder()
    win_s = [(1.0, 2.8, 0.9, 2.3), (4.2, 6.0, 0.9, 2.3), (8.0, 9.6, 0.9, 2.3)]  # y = 0 wall, along +x
    win_e = [(1.2, 3.2, 0.9, 2.3)]                                           # x = 10 wall, along +y
    win_w = [(5.0, 6.5, 0.9, 2.3)]                                           # x = 0 wall, along -y from y = 8
    door = (1.0, 2.0, 0.0, 2.1)                                              # y = 8 wall, along +x from x = 0
    glass_door = (3.2, 4.1, 0.0, 2.1)                                        # gap in the glass wall, along +y
    shell = (0.85, 0.84, 0.80)
    b.add("floor", _merge([rect_xy(*OFFICE_AREAS[k], 0.0, up=True) for k in ("main", "wing")]), "concrete", "carpet",
          (0.40, 0.42, 0.45), 0.2)
    b.add("ceiling", _merge([rect_xy(*OFFICE_AREAS[k], lz, up=False) for k in ("main", "wing")]), "concrete",
          "plaster", (0.93, 0.92, 0.90), 0.2)
    b.add("wall_south", wall((mx0, my0, 0), (1, 0, 0), (0, 1, 0), mx1 - mx0, lz, win_s), "concrete", "plaster",
          shell, 0.2)
    b.add("wall_east", wall((mx1, my0, 0), (0, 1, 0), (-1, 0, 0), my1 - my0, lz, win_e), "concrete", "brick",
          (0.62, 0.33, 0.25), 0.2)
    b.add("wall_core", _merge([wall((wx1, my1, 0), (1, 0, 0), (0, -1, 0), mx1 - wx1, lz),
                               wall((wx1, wy0, 0), (0, 1, 0), (-1, 0, 0), wy1 - wy0, lz)]),
          "concrete", "plaster", (0.78, 0.80, 0.84), 0.2)
    b.add("wall_north", wall((wx0, wy1, 0), (1, 0, 0), (0, -1, 0), wx1 - wx0, lz, [door]), "concrete", "plaster",
          shell, 0.2)
    b.add("wall_west", wall((mx0, wy1, 0), (0, -1, 0), (1, 0, 0), wy1 - my0, lz, win_w), "concrete", "plaster",
          (0.80, 0.82, 0.76), 0.2)
    panes = [((u0, my0, z0), (1, 0, 0), (0, 1, 0), u1 - u0, z1 - z0) for u0, u1, z0, z1 in win_s]
    panes += [((mx1, my0 + u0, z0), (0, 1, 0), (-1, 0, 0), u1 - u0, z1 - z0) for u0, u1, z0, z1 in win_e]
    panes += [((mx0, wy1 - u0, z0), (0, -1, 0), (1, 0, 0), u1 - u0, z1 - z0) for u0, u1, z0, z1 in win_w]
    for i, args in enumerate(panes):
        b.add(f"window_{i:02d}", wall(*args), "glass", "glass", (0.70, 0.82, 0.88), 0.006)
    b.add("door", wall((door[0], wy1, 0.0), (1, 0, 0), (0, -1, 0), door[1] - door[0], door[3]), "wood", "wood",
          (0.55, 0.36, 0.20), 0.04)
    # the glass partition: one two-sided pane from the south wall to the core, floor to ceiling
    b.add("glass_partition", wall((gx, my0, 0), (0, 1, 0), (-1, 0, 0), my1 - my0, lz, [glass_door]), "glass", "glass",
          (0.75, 0.86, 0.90), 0.012)
    steel, wood = (0.80, 0.81, 0.83), (0.62, 0.45, 0.28)
    b.add("cabinet_00", box((0.02, 0.4, 0.0), (0.5, 0.9, 1.3)), "metal", "metal", steel, 0.002)
    b.add("cabinet_01", box((0.02, 0.95, 0.0), (0.5, 1.45, 1.3)), "metal", "metal", steel, 0.002)
    b.add("cupboard", box((wx1 - 0.5, 6.6, 0.0), (wx1 - 0.02, 7.8, 2.0)), "metal", "metal", (0.55, 0.58, 0.62), 0.002)
    b.add("shelving", _metal_shelving(0.02, 4.8, 0.42, 6.2), "metal", "metal", steel, 0.002)
    desks = [(2.2, 1.6), (3.6, 1.6), (2.2, 3.2), (3.6, 3.2), (5.6, 2.4), (2.0, 6.4), (3.5, 6.4)]
    for k, (x, y) in enumerate(desks):
        b.add(f"desk_{k:02d}", _desk(x, y), "wood", "wood", wood, 0.03)
        b.add(f"chair_{k:02d}", _chair(x, y + (0.55 if y in (3.2, 6.4) else -0.55), facing=-np.pi / 2 if y in (3.2, 6.4)
                                        else np.pi / 2), "wood", "plastic", (0.2, 0.3, 0.6), 0.02)
    # meeting room (x gx..10, y 0..4.5): a long table and two chairs
    b.add("meeting_table", _desk(8.8, 2.2, w=1.0, d=2.2), "wood", "wood", (0.45, 0.30, 0.18), 0.03)
    for k, y in enumerate((1.6, 2.8)):
        b.add(f"meeting_chair_{k:02d}", _chair(9.65, y, facing=np.pi), "wood", "plastic", (0.15, 0.20, 0.45), 0.02)
    return SceneSpec("office", "room", b.objects, np.array([[0.0, 0.0, 0.0], [lx, ly, lz]]),
                     info={"size_m": [lx, ly, lz], "areas": {k: list(v) for k, v in OFFICE_AREAS.items()},
                           "glass_partition_x_m": gx})


def empty() -> SceneSpec:
    """No objects at all: free space (Friis checks). Bounds are nominal."""
    return SceneSpec("empty", "room", [], np.array([[-5.0, -5.0, -5.0], [5.0, 5.0, 5.0]]))


def plate(size_m: float = 4.0, thickness_m: float = 0.0, at_x: float = 0.0) -> SceneSpec:
    """A square metal plate in the plane x = at_x, facing +x (physics checks).

    thickness_m = 0 gives a single rectangle (one face); > 0 a box.
    """
    h = size_m / 2
    b = _Builder()
    if thickness_m > 0:
        mesh = box((at_x - thickness_m, -h, -h), (at_x, h, h))
    else:
        mesh = wall((at_x, -h, -h), (0, 1, 0), (1, 0, 0), size_m, size_m)
    b.add("plate", mesh, "metal", "metal", (0.8, 0.8, 0.82), 0.002)
    return SceneSpec("plate", "object", b.objects, _bounds(b.objects), info={"size_m": size_m})


def ground_plate(size_m: float = 40.0) -> SceneSpec:
    """A large horizontal metal plate at z = 0, facing up (two-ray check)."""
    h = size_m / 2
    b = _Builder()
    b.add("ground", rect_xy(-h, h, -h, h, 0.0, up=True), "metal", "metal", (0.8, 0.8, 0.82), 0.002)
    return SceneSpec("ground-plate", "room", b.objects, _bounds(b.objects), info={"size_m": size_m})


LEGO_UNIT_M = 0.04  # one stud pitch: a 5x scaled brick (real pitch 8 mm)
LEGO_PLATE_H_M = 0.048  # brick height (5 x 9.6 mm)
_LEGO_COLORS = {"red": (0.75, 0.08, 0.06), "blue": (0.05, 0.25, 0.65), "yellow": (0.95, 0.78, 0.05),
                "green": (0.10, 0.50, 0.20), "white": (0.92, 0.92, 0.90), "black": (0.08, 0.08, 0.09)}


# The assembly: (i, j, layer, nx, ny, colour) per brick, in stud pitches and brick layers. Bricks of a layer
# never share volume (tests/simulate/test_scenes.py): coincident faces of two overlapping boxes would carry
# the physical-optics current twice (the PO solver integrates every facet it finds lit).
LEGO_LAYOUT = [
    (0, 0, 0, 4, 2, "red"), (4, 0, 0, 4, 2, "blue"), (8, 0, 0, 2, 2, "yellow"),
    (0, 2, 0, 4, 2, "green"), (4, 2, 0, 4, 2, "red"), (8, 2, 0, 2, 2, "white"),
    (0, 4, 0, 4, 2, "yellow"), (4, 4, 0, 4, 2, "blue"), (8, 4, 0, 2, 2, "red"),
    (1, 1, 1, 4, 2, "white"), (5, 1, 1, 4, 2, "yellow"), (1, 3, 1, 4, 2, "blue"), (5, 3, 1, 4, 2, "green"),
    (2, 1, 2, 2, 4, "red"), (4, 2, 2, 2, 2, "black"), (6, 1, 2, 2, 4, "blue"),
    (3, 2, 3, 4, 2, "yellow"), (3, 2, 4, 2, 2, "red"), (5, 2, 4, 2, 2, "white"),
    (4, 2, 5, 2, 2, "green"),
]


def _lego_brick(i, j, k, nx, ny):
    """Brick of nx x ny studs with its lower corner at stud (i, j), layer k; with its studs."""
    u, hgt = LEGO_UNIT_M, LEGO_PLATE_H_M
    lo = (i * u, j * u, k * hgt)
    hi = ((i + nx) * u, (j + ny) * u, (k + 1) * hgt)
    parts = [(lo, hi)]
    s, sh = 0.4 * u, 0.2 * hgt  # square studs (keeps the mesh small and its faces flat)
    for a in range(nx):
        for c in range(ny):
            cx, cy = (i + a + 0.5) * u, (j + c + 0.5) * u
            parts.append(((cx - s / 2, cy - s / 2, hi[2]), (cx + s / 2, cy + s / 2, hi[2] + sh)))
    return boxes(parts)


def lego() -> SceneSpec:
    """A stepped brick assembly, about 0.40 x 0.24 x 0.34 m, bricks as separate labelled objects.

    Radio material: ABS plastic (eps_r ~ 2.7) is not an ITU material; "plasterboard" has
    eps_r = 2.73 and low loss, so it stands in, with 0.0075 m walls (hollow bricks, 5x 1.5 mm).
    """
    b = _Builder()
    for n, (i, j, k, nx, ny, col) in enumerate(LEGO_LAYOUT):
        b.add(f"brick_{n:02d}", _lego_brick(i, j, k, nx, ny), "plasterboard", "plastic", _LEGO_COLORS[col], 0.0075)
    _centre_objects(b.objects)
    return SceneSpec("lego", "object", b.objects, _bounds(b.objects), info={"material_note": "ABS ~ plasterboard"})


def h_target(width=0.5, depth=0.2, height=0.6, bar=0.12) -> SceneSpec:
    """A metal letter H, 0.5 (x) x 0.2 (y) x 0.6 (z) m: two uprights and a crossbar, one object."""
    w, d, h = width, depth, height
    mesh = boxes([
        ((-w / 2, -d / 2, -h / 2), (-w / 2 + bar, d / 2, h / 2)),
        ((w / 2 - bar, -d / 2, -h / 2), (w / 2, d / 2, h / 2)),
        ((-w / 2 + bar, -d / 2, -bar / 2), (w / 2 - bar, d / 2, bar / 2)),
    ])
    b = _Builder()
    b.add("h_target", mesh, "metal", "metal", (0.72, 0.73, 0.75), 0.003)
    return SceneSpec("h-target", "object", b.objects, _bounds(b.objects), info={"size_m": [w, d, h]})


def trio() -> SceneSpec:
    """Three objects of different ITU materials on one turntable, about 0.5 x 0.5 x 0.3 m: a metal
    dihedral (two 0.2 x 0.25 m plates, 3 mm, meeting at 90 degrees: a double-bounce flash at its
    bisector), a wooden block (0.16 x 0.10 x 0.12 m) and a glass pane (0.25 x 0.25 m, 6 mm), each
    its own label, so that materials can be recovered per object."""
    b = _Builder()
    t = 0.003
    dihedral = boxes([((0.05, 0.05, -0.125), (0.05 + 0.2, 0.05 + t, 0.125)),
                      ((0.05, 0.05, -0.125), (0.05 + t, 0.05 + 0.2, 0.125))])
    b.add("dihedral", dihedral, "metal", "metal", (0.72, 0.73, 0.75), t)
    b.add("block", box((-0.25, 0.05, -0.06), (-0.09, 0.15, 0.06)), "wood", "wood", (0.60, 0.42, 0.25), 0.1)
    pane = rotate_z(np.asarray(box((-0.003, -0.125, -0.125), (0.003, 0.125, 0.125))[0]), math.radians(30.0))
    b.add("pane", (pane + np.array([-0.1, -0.15, 0.0]), box((0, 0, 0), (1, 1, 1))[1]), "glass", "glass",
          (0.75, 0.85, 0.9), 0.006)
    _centre_objects(b.objects)
    return SceneSpec("trio", "object", b.objects, _bounds(b.objects),
                     info={"materials": {"dihedral": "metal", "block": "wood", "pane": "glass"}})


CAR_LENGTH_M = 0.45  # the low-poly car, scaled to a model car that fits inside 2 m range


def _read_ply_xyz_faces(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Minimal binary little-endian PLY reader (vertex x, y, z + float extras; triangle list)."""
    data = path.read_bytes()
    end = data.index(b"end_header") + len(b"end_header")
    end += 2 if data[end:end + 2] == b"\r\n" else 1
    header = data[:end].decode("ascii").splitlines()
    if not any("binary_little_endian" in h for h in header):
        raise ValueError(f"{path}: only binary little-endian PLY is supported")
    nv = nf = 0
    vprops: list[str] = []
    cur = None
    sizes = {"float": 4, "float32": 4, "double": 8, "float64": 8, "uchar": 1, "uint8": 1, "int": 4,
             "int32": 4, "uint": 4, "uint32": 4}
    for h in header:
        t = h.split()
        if t[:2] == ["element", "vertex"]:
            nv, cur = int(t[2]), "v"
        elif t[:2] == ["element", "face"]:
            nf, cur = int(t[2]), "f"
        elif t and t[0] == "property" and cur == "v":
            vprops.append(t[1])
    fmt = {"float": "f", "float32": "f", "double": "d", "float64": "d", "uchar": "B", "uint8": "B",
           "int": "i", "int32": "i", "uint": "I", "uint32": "I"}
    vfmt = "<" + "".join(fmt[p] for p in vprops)
    vsize = sum(sizes[p] for p in vprops)
    verts = np.array([struct.unpack_from(vfmt, data, end + i * vsize)[:3] for i in range(nv)], np.float64)
    off = end + nv * vsize
    faces = []
    for _ in range(nf):
        n = data[off]
        idx = struct.unpack_from(f"<{n}i", data, off + 1)
        off += 1 + 4 * n
        faces.extend([idx[0], idx[k], idx[k + 1]] for k in range(1, n - 1))
    return verts, np.array(faces, np.int32)


def sionna_car_path() -> Path:
    try:
        import sionna.rt  # noqa: F401 - only to locate its package data
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("scene 'car' needs sionna-rt (pip install 'rfir[sim]')") from e
    import sionna.rt as srt
    return Path(srt.__file__).parent / "scenes" / "low_poly_car.ply"


def car(length_m: float = CAR_LENGTH_M) -> SceneSpec:
    """Sionna's low-poly car mesh, centred on the origin and scaled to length_m (metal body)."""
    v, f = _read_ply_xyz_faces(sionna_car_path())
    # unshare vertices so every triangle is flat-shaded
    v = v[f.reshape(-1)]
    f = np.arange(len(v), dtype=np.int32).reshape(-1, 3)
    ext = v.max(0) - v.min(0)
    v = v * (length_m / ext.max())
    obj = SceneObject("car", 0, v, f, "metal", "metal", (0.70, 0.10, 0.08), 0.002)
    # make winding outward: orient each face away from the centroid (the car is convex-ish)
    c = 0.5 * (v.min(0) + v.max(0))
    n = obj.face_normals()
    centres = v[f].mean(1)
    flip = np.einsum("ij,ij->i", n, centres - c) < 0
    obj.faces[flip] = obj.faces[flip][:, [0, 2, 1]]
    _centre_objects([obj])
    return SceneSpec("car", "object", [obj], _bounds([obj]), info={"source": "sionna-rt low_poly_car.ply",
                                                                   "length_m": length_m})


_BUILDERS = {"classroom": classroom, "flat": flat, "office": office, "lego": lego, "car": car, "h-target": h_target,
             "plate": plate, "trio": trio,
             "empty": empty, "ground-plate": ground_plate}


def build_scene(name: str) -> SceneSpec:
    """Build one of SCENES (plus "ground-plate" for physics checks); ValueError if unknown."""
    key = name.lower().replace("_", "-")
    if key == "h":
        key = "h-target"
    if key not in _BUILDERS:
        raise ValueError(f"unknown scene {name!r} (known: {', '.join(SCENES)})")
    return _BUILDERS[key]()


# --------------------------------------------------------------------------------------------
# PLY output
# --------------------------------------------------------------------------------------------
def write_ply(path: Path, vertices: np.ndarray, faces: np.ndarray, vertex_label: np.ndarray | None = None,
              face_label: np.ndarray | None = None) -> Path:
    """Binary little-endian PLY: float x, y, z (+ int label) per vertex; int list (+ int label) per face."""
    path = Path(path)
    vl = vertex_label is not None
    fl = face_label is not None
    head = ["ply", "format binary_little_endian 1.0", f"element vertex {len(vertices)}",
            "property float x", "property float y", "property float z"]
    if vl:
        head.append("property int label")
    head += [f"element face {len(faces)}", "property list uchar int vertex_indices"]
    if fl:
        head.append("property int label")
    head.append("end_header")
    vdt = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")] + ([("label", "<i4")] if vl else [])
    va = np.empty(len(vertices), dtype=vdt)
    va["x"], va["y"], va["z"] = vertices[:, 0], vertices[:, 1], vertices[:, 2]
    if vl:
        va["label"] = vertex_label
    fdt = [("n", "u1"), ("i", "<i4", (3,))] + ([("label", "<i4")] if fl else [])
    fa = np.empty(len(faces), dtype=fdt)
    fa["n"] = 3
    fa["i"] = faces
    if fl:
        fa["label"] = face_label
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        fh.write(("\n".join(head) + "\n").encode("ascii"))
        fh.write(va.tobytes())
        fh.write(fa.tobytes())
    return path


def combined_mesh(spec: SceneSpec) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """All objects in one mesh: vertices, faces, vertex labels, face labels."""
    vs, fs, vl, fl, off = [], [], [], [], 0
    for o in spec.objects:
        vs.append(o.vertices)
        fs.append(o.faces + off)
        vl.append(np.full(len(o.vertices), o.label, np.int32))
        fl.append(np.full(len(o.faces), o.label, np.int32))
        off += len(o.vertices)
    if not vs:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int32), np.zeros(0, np.int32), np.zeros(0, np.int32)
    return np.concatenate(vs), np.concatenate(fs), np.concatenate(vl), np.concatenate(fl)


def write_meshes(spec: SceneSpec, folder) -> list[Path]:
    """Write <folder>/<object>.ply per object (with its label) and <folder>/<scene>_gt.ply combined.

    Also writes <folder>/labels.json mapping label id -> name and materials.
    Returns the PLY paths, per-object ones first and the combined one last.
    """
    import json

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for o in spec.objects:
        out.append(write_ply(folder / f"{o.name}.ply", o.vertices, o.faces,
                             np.full(len(o.vertices), o.label, np.int32), np.full(len(o.faces), o.label, np.int32)))
    v, f, vl, fl = combined_mesh(spec)
    out.append(write_ply(folder / f"{spec.name}_gt.ply", v, f, vl, fl))
    labels = [{"label": o.label, "name": o.name, "radio_material": o.radio_material, "visual": o.visual,
               "color": list(o.color), "thickness_m": o.thickness_m, "faces": int(len(o.faces))}
              for o in spec.objects]
    (folder / "labels.json").write_text(json.dumps({"scene": spec.name, "objects": labels}, indent=1))
    return out
