"""A room's shell from its planes (planes.py): floor, ceiling and walls, snapped to meet at their edges, each with
its extent and openings, for `rfir structure`.

The frame is the artifact's (z up, metres, as `rfir calibrate` aligns it). A plane is part of the shell when
(almost) every Gaussian of the scene lies on one side of it: the floor has them above, the ceiling below, a
wall in front. Walls are vertical planes spanning a good part of the room's height; coplanar pieces of one
wall are joined. Floor and ceiling snap to horizontal and walls to vertical when they are within `snap_deg`
of it (their measured tilts are kept for the frame check). A wall's ends move to where it meets the
neighbouring wall when that is within `corner_m` of them; its height runs from the floor to the ceiling.
Without a ceiling plane (photos barely see it) the ceiling is placed at the walls' top.

Extents are occupancy grids of `cell_m` cells in each surface's plane. A wall's cells are those holding its
Gaussians, less the cells of stray ones (fewer than two occupied neighbours), closed over gaps up to 2
`close_m` wide (the Gaussians' own gaps), empty pieces smaller than (2 `close_m`)^2 filled (gaps along the
edges). What stays empty is an opening where a square of `min_opening_m` fits in it (a door, a window the
photos see through); a strip along the floor hidden by furniture is wall. Floor and ceiling cover the polygon
the walls' ends enclose: what furniture hides there is floor all the same.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .planes import Plane, fit_plane

UP = np.array([0.0, 0.0, 1.0])


@dataclass
class ShellSettings:
    """Thresholds of the shell (configs/geom.toml [geom.structure]): angles in degrees, lengths in metres."""
    distance_m: float = 0.06
    class_deg: float = 20.0
    snap_deg: float = 3.0
    boundary_share: float = 0.05
    min_wall_height_share: float = 0.4
    min_wall_length_m: float = 1.0
    corner_m: float = 1.0
    cell_m: float = 0.1
    close_m: float = 0.3
    min_opening_m: float = 0.5


@dataclass
class Surface:
    """A shell surface. kind: floor, ceiling or wall; normal [3] unit, into the room; offset [m] (normal . x on the
    plane); members [M]: Gaussians on it; origin [3], u [3], v [3]: its extent's corner and in-plane unit axes;
    occupied [nu, nv] bool: cell (i, j) of cell_m at origin + (i + 1/2) cell u + (j + 1/2) cell v is surface
    (False: an opening); tilt_deg: the fitted plane's angle from horizontal (floor, ceiling) or vertical (wall)
    before snapping (nan when inferred); inferred: placed from other surfaces (a ceiling at the walls' top);
    inset_cells [nu, nv] bool: a surface's cells given to its insets (insets.py), None without."""
    name: str
    kind: str
    normal: np.ndarray
    offset: float
    members: np.ndarray
    tilt_deg: float
    inferred: bool = False
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    u: np.ndarray = field(default_factory=lambda: np.zeros(3))
    v: np.ndarray = field(default_factory=lambda: np.zeros(3))
    occupied: np.ndarray = field(default_factory=lambda: np.zeros((0, 0), bool))
    cell_m: float = 0.1

    @property
    def size_m(self) -> tuple[float, float]:
        """Extent along u and v [m]."""
        return self.occupied.shape[0] * self.cell_m, self.occupied.shape[1] * self.cell_m

    inset_cells: np.ndarray | None = None

    @property
    def openings_m2(self) -> float:
        """Area [m^2] of the empty cells within the bounding box of the occupied ones, less those of its insets."""
        if not self.occupied.any():
            return 0.0
        i, j = np.nonzero(self.occupied)
        empty = ~self.occupied if self.inset_cells is None else ~(self.occupied | self.inset_cells)
        return float(empty[i.min():i.max() + 1, j.min():j.max() + 1].sum()) * self.cell_m ** 2


def _tilt_from_vertical_deg(normal: np.ndarray) -> float:
    return float(np.degrees(np.arcsin(min(1.0, abs(normal @ UP)))))


def _tilt_from_horizontal_deg(normal: np.ndarray) -> float:
    return float(np.degrees(np.arccos(min(1.0, abs(normal @ UP)))))


def _inward(plane: Plane, x: np.ndarray, settings: ShellSettings) -> tuple[np.ndarray, float, float] | None:
    """(normal, offset) of the plane turned to the side that holds the scene's Gaussians x [N, 3], and the share
    of them on the other side; None when both sides hold more than boundary_share (not a boundary)."""
    d = plane.distance(x)
    above, below = float(np.mean(d > settings.distance_m)), float(np.mean(d < -settings.distance_m))
    if min(above, below) > settings.boundary_share:
        return None
    return (plane.normal, plane.offset, below) if above >= below else (-plane.normal, -plane.offset, above)


def build_shell(x: np.ndarray, planes: list[Plane], settings: ShellSettings) -> list[Surface]:
    """The shell's surfaces (floor, ceiling, walls; module docstring) from the planes of Gaussians x [N, 3] m.
    Raises ValueError naming what is missing when no floor or fewer than two walls are found."""
    cos_class = np.cos(np.radians(settings.class_deg))
    floors, ceilings, walls = [], [], []
    z_lo, z_hi = np.percentile(x[:, 2], [1, 99])
    for plane in planes:
        turned = _inward(plane, x, settings)
        if turned is None:
            continue
        normal, offset, _ = turned
        vertical_share = abs(normal @ UP)
        if vertical_share >= cos_class:
            (floors if normal[2] > 0 else ceilings).append((plane, normal, offset))
        elif vertical_share <= np.sin(np.radians(settings.class_deg)):
            z = x[plane.members, 2]
            height = np.percentile(z, 98) - np.percentile(z, 2)
            along = np.cross(UP, normal)
            s = x[plane.members] @ along
            length = np.percentile(s, 99) - np.percentile(s, 1)
            if height >= settings.min_wall_height_share * (z_hi - z_lo) and length >= settings.min_wall_length_m:
                walls.append((plane, normal, offset))
    if not floors:
        raise ValueError("no floor: no horizontal plane with the scene's Gaussians above it")
    walls = _join_coplanar(x, walls, settings)
    if len(walls) < 2:
        raise ValueError(f"{len(walls)} wall(s) found: a room needs vertical planes on at least two sides")
    floor_plane = max(floors, key=lambda f: len(f[0].members))
    floor = _snapped(x, "floor", floor_plane[0].members, floor_plane[1], settings)
    wall_surfaces = [_snapped(x, f"wall_{k:02d}", w[0].members, w[1], settings) for k, w in enumerate(walls)]
    top = float(np.percentile(x[np.concatenate([w.members for w in wall_surfaces]), 2], 99.9))
    # ceiling candidates: horizontal boundaries with the Gaussians below, at or above the walls' top
    near_top = [c for c in ceilings if -c[2] >= top - 3 * settings.distance_m - 0.3]
    if near_top:
        plane, normal, _ = max(near_top, key=lambda c: len(c[0].members))
        ceiling = _snapped(x, "ceiling", plane.members, normal, settings)
    else:
        ceiling = Surface("ceiling", "ceiling", -UP.copy(), -top, np.zeros(0, np.int64), float("nan"), inferred=True)
    _wall_extents(x, wall_surfaces, floor, ceiling, settings)
    polygon = _wall_polygon(wall_surfaces)
    for flat in (floor, ceiling):
        _flat_extent(flat, polygon, settings)
    return [floor, ceiling, *wall_surfaces]


def _join_coplanar(x, walls, settings: ShellSettings):
    """Walls whose planes agree (normals within snap_deg, offsets within 2 distance_m) joined into one."""
    out: list[tuple[Plane, np.ndarray, float]] = []
    cos_same = np.cos(np.radians(max(settings.snap_deg, 5.0)))
    for plane, normal, offset in sorted(walls, key=lambda w: -len(w[0].members)):
        for k, (p2, n2, o2) in enumerate(out):
            if normal @ n2 >= cos_same and abs(offset - o2) <= 2 * settings.distance_m:
                members = np.union1d(p2.members, plane.members)
                n_fit, o_fit, rms = fit_plane(x[members])
                if n_fit @ n2 < 0:
                    n_fit, o_fit = -n_fit, -o_fit
                out[k] = (Plane(n_fit, o_fit, members, rms), n_fit, o_fit)
                break
        else:
            out.append((plane, normal, offset))
    return out


def _snapped(x, name: str, members: np.ndarray, normal: np.ndarray, settings: ShellSettings) -> Surface:
    """A surface on the members' plane (normal into the room), snapped to horizontal (floor, ceiling) or vertical
    (wall) when within snap_deg; the offset the members' median distance along the (snapped) normal."""
    kind = name.split("_")[0]
    if kind == "wall":
        tilt = _tilt_from_vertical_deg(normal)
        if tilt <= settings.snap_deg:
            normal = normal - (normal @ UP) * UP
    else:
        tilt = _tilt_from_horizontal_deg(normal)
        if tilt <= settings.snap_deg:
            normal = np.sign(normal[2]) * UP
    normal = normal / np.linalg.norm(normal)
    return Surface(name, kind, normal, float(np.median(x[members] @ normal)), members, tilt)


def _wall_extents(x, walls: list[Surface], floor: Surface, ceiling: Surface, settings: ShellSettings) -> None:
    """Each wall's extent (ends met with the neighbouring walls, floor to ceiling) and occupancy grid."""
    from scipy import ndimage

    z0 = _height_at(floor)
    z1 = _height_at(ceiling)
    for wall in walls:
        along = np.cross(UP, wall.normal)
        along /= np.linalg.norm(along)
        s = x[wall.members] @ along
        ends = [float(np.percentile(s, 0.5)), float(np.percentile(s, 99.5))]
        for other in walls:
            if other is wall or abs(other.normal @ wall.normal) > np.cos(np.radians(30)):
                continue
            corner = _meeting_point(wall, other)
            s_corner = float(corner @ along)
            other_along = np.cross(UP, other.normal)
            t = x[other.members] @ (other_along / np.linalg.norm(other_along))
            t_corner = float(corner @ other_along / np.linalg.norm(other_along))
            near_other_end = min(abs(t_corner - np.percentile(t, 0.5)), abs(t_corner - np.percentile(t, 99.5)))
            if near_other_end > settings.corner_m:
                continue
            k = int(np.argmin([abs(s_corner - e) for e in ends]))
            if abs(s_corner - ends[k]) <= settings.corner_m:
                ends[k] = s_corner
        base = wall.offset * wall.normal
        wall.u, wall.v = along, UP.copy()
        wall.origin = base + ends[0] * along + z0 * UP - (base @ UP) * UP
        wall.cell_m = settings.cell_m
        shape = (max(1, int(round((ends[1] - ends[0]) / settings.cell_m))), max(1, int(round((z1 - z0) / settings.cell_m))))
        near = np.abs(x @ wall.normal - wall.offset) <= settings.distance_m     # every Gaussian on the wall counts
        closed = _closed(_cells(x[near], wall, shape), int(round(settings.close_m / settings.cell_m)))
        # an opening is one a min_opening_m square fits in (a door, a window); narrower gaps, such as the strips
        # along the floor behind the furniture and under the ceiling that photos do not see, are wall
        k = max(1, int(round(settings.min_opening_m / settings.cell_m)))
        wall.occupied = ~ndimage.binary_opening(~closed, np.ones((k, k), bool))


def _height_at(flat: Surface) -> float:
    """Height [m] of a horizontal surface (offset along its +-z normal)."""
    return float(flat.offset * np.sign(flat.normal[2]))


def _meeting_point(a: Surface, b: Surface) -> np.ndarray:
    """[3] point at z = 0 on the line where vertical walls a and b meet."""
    m = np.array([a.normal[:2], b.normal[:2]])
    xy = np.linalg.solve(m, np.array([a.offset, b.offset]))
    return np.array([xy[0], xy[1], 0.0])


def _wall_polygon(walls: list[Surface]) -> np.ndarray:
    """[K, 2] the walls' end points in xy, ordered by angle about their centroid (the room's outline for a room
    every wall of which is seen from its centre), near-duplicate corners joined."""
    pts = []
    for w in walls:
        for s in (0.0, w.size_m[0]):
            p = (w.origin + s * w.u)[:2]
            if not any(np.linalg.norm(p - q) < 2 * w.cell_m for q in pts):
                pts.append(p)
    pts = np.array(pts)
    c = pts.mean(0)
    return pts[np.argsort(np.arctan2(pts[:, 1] - c[1], pts[:, 0] - c[0]))]


def _flat_extent(flat: Surface, polygon: np.ndarray, settings: ShellSettings) -> None:
    """Floor or ceiling: the polygon's bounding box as its grid, the cells inside the polygon its surface."""
    from matplotlib.path import Path as PolygonPath

    lo, hi = polygon.min(0), polygon.max(0)
    z = _height_at(flat)
    flat.u, flat.v = np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])
    flat.origin = np.array([lo[0], lo[1], z])
    flat.cell_m = settings.cell_m
    shape = np.maximum(1, np.round((hi - lo) / settings.cell_m).astype(int))
    i, j = np.meshgrid(np.arange(shape[0]) + 0.5, np.arange(shape[1]) + 0.5, indexing="ij")
    centres = lo + settings.cell_m * np.stack([i.ravel(), j.ravel()], 1)
    inside = PolygonPath(polygon).contains_points(centres, radius=1e-9)
    flat.occupied = inside.reshape(shape[0], shape[1])


def _cells(x: np.ndarray, surface: Surface, shape: tuple[int, int]) -> np.ndarray:
    """[nu, nv] bool: the cells holding one of the points x [N, 3] (projected onto the surface)."""
    rel = x - surface.origin
    i = np.floor(rel @ surface.u / surface.cell_m).astype(int)
    j = np.floor(rel @ surface.v / surface.cell_m).astype(int)
    ok = (i >= 0) & (i < shape[0]) & (j >= 0) & (j < shape[1])
    grid = np.zeros(shape, bool)
    grid[i[ok], j[ok]] = True
    return grid


def _closed(grid: np.ndarray, r: int) -> np.ndarray:
    """Morphological closing with a disk of r cells; outside the grid counts as empty, so the closing neither eats
    nor fills the border (an opening at the edge, a door at the floor, stays open)."""
    from scipy import ndimage

    if r <= 0:
        return grid
    # a stray Gaussian in an opening (an outlier, a floater) would close it: cells with fewer than two occupied
    # neighbours of their 8 do not count
    neighbours = ndimage.convolve(grid.astype(np.int64), np.ones((3, 3), np.int64), mode="constant") - grid
    padded = np.pad(grid & (neighbours >= 2), r + 1)
    disk = np.hypot(*np.mgrid[-r:r + 1, -r:r + 1]) <= r
    closed = ndimage.binary_erosion(ndimage.binary_dilation(padded, disk), disk, border_value=0)[r + 1:-r - 1, r + 1:-r - 1]
    # what the closing leaves along the border of sparse Gaussians: empty pieces smaller than the disk's square
    pieces, count = ndimage.label(~closed)
    small = np.flatnonzero(np.bincount(pieces.ravel(), minlength=count + 1)[1:] < (2 * r) ** 2) + 1
    return closed | np.isin(pieces, small)


def rectangles(grid: np.ndarray) -> list[tuple[int, int, int, int]]:
    """The True cells of grid [nu, nv] as disjoint rectangles (i0, j0, i1, j1), cells i0 <= i < i1, j0 <= j < j1:
    greedy, each as long along v and then as wide along u as the cells allow."""
    left = grid.copy()
    out = []
    for i0, j0 in zip(*np.nonzero(grid)):
        if not left[i0, j0]:
            continue
        j1 = j0
        while j1 < grid.shape[1] and left[i0, j1]:
            j1 += 1
        i1 = i0 + 1
        while i1 < grid.shape[0] and left[i1, j0:j1].all():
            i1 += 1
        left[i0:i1, j0:j1] = False
        out.append((int(i0), int(j0), int(i1), int(j1)))
    return out


def surface_quads(surface: Surface) -> tuple[np.ndarray, np.ndarray]:
    """The surface's rectangles as a triangle mesh: vertices [4R, 3] m, faces [2R, 3] wound so that their normal is
    the surface's (into the room)."""
    verts, faces = [], []
    flip = np.cross(surface.u, surface.v) @ surface.normal < 0
    for k, (i0, j0, i1, j1) in enumerate(rectangles(surface.occupied)):
        c = surface.cell_m
        corners = [surface.origin + a * c * surface.u + b * c * surface.v for a, b in ((i0, j0), (i1, j0), (i1, j1), (i0, j1))]
        verts += corners
        tri = [[0, 1, 2], [0, 2, 3]] if not flip else [[0, 2, 1], [0, 3, 2]]
        faces += [[4 * k + t for t in f] for f in tri]
    return np.asarray(verts, float).reshape(-1, 3), np.asarray(faces, np.int64).reshape(-1, 3)
