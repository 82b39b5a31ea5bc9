"""A room's shell from its planes (planes.py): floor, ceiling and walls, snapped to meet at their edges, each with
its extent and openings, for `rfir structure`.

The frame is the artifact's (z up, metres, as `rfir calibrate` aligns it). A plane is part of the shell when
(almost) no Gaussian lies behind it within its own extent: the floor has the scene above, the ceiling below, a
wall in front. Within its extent, not across the whole plane: the two walls at an L-shaped room's inner corner
have the room's other wing behind their planes' continuation, not behind themselves. Walls are vertical planes
spanning a good part of the room's height; coplanar pieces of one wall are joined. Floor and ceiling snap to
horizontal and walls to vertical when they are within `snap_deg` of it (their measured tilts are kept for the
frame check). Neighbouring walls meet where their planes intersect: each wall end takes the nearest such corner
within `corner_m` of it and of the other wall's end (one corner per end), and the room's outline is the walls
in order around it, corner to corner (a rectilinear or any simple polygon; across a gap where no wall was
found, straight to the next wall). A wall's height runs from the floor to the ceiling. Without a ceiling plane
(photos barely see it) the ceiling is placed at the walls' top.

Gaussians count by their footprints (planes.footprint_areas_m2): medians, percentiles and fits are weighted by
area, and a Gaussian's extent reaches half its footprint's side beyond its centre, so the surfels of a mesh
(tens of centimetres) and photo Gaussians (centimetres) give the same surfaces. Extents are occupancy grids of
`cell_m` cells in each surface's plane. A wall's cells are those its Gaussians' footprints cover, less the
cells of stray ones (fewer than two occupied neighbours), closed over gaps up to 2 `close_m` wide (the
Gaussians' own gaps), empty pieces smaller than (2 `close_m`)^2 filled (gaps along the edges). What stays
empty is an opening where a square of `min_opening_m` fits in it (a door, a window the photos see through); a
strip along the floor hidden by furniture is wall. Floor and ceiling cover the room's outline: what furniture
hides there is floor all the same.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .planes import Plane, fit_plane, votes_and_radii, weighted_quantile

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
        """Extent along u and v [m]: the grid's; an inset's, which lives on its host's grid, that of its own cells."""
        if self.kind == "inset" and self.occupied.any():
            iu, iv = np.nonzero(self.occupied)
            return (np.ptp(iu) + 1) * self.cell_m, (np.ptp(iv) + 1) * self.cell_m
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


def _in_plane_axes(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit axes [3] in the plane of the unit normal: for a wall along it and up, for a level plane x and y."""
    along = np.cross(UP, normal)
    if np.linalg.norm(along) < 1e-6:
        along = np.array([1.0, 0.0, 0.0]) - normal[0] * normal
    along /= np.linalg.norm(along)
    return along, np.cross(normal, along)


def _within_extent(plane: Plane, x: np.ndarray, margin_m: float, points: np.ndarray | None = None) -> np.ndarray:
    """[P] bool: which points [P, 3] (None: all of x) project within the plane's extent (its members' 1st to 99th
    percentile along its two in-plane axes, the members indices into the Gaussians x [N, 3]) less margin_m at
    each edge."""
    points = x if points is None else points
    within = np.ones(len(points), bool)
    for axis in _in_plane_axes(plane.normal):
        lo, hi = np.percentile(x[plane.members] @ axis, [1, 99])
        c = points @ axis
        within &= (c >= lo + margin_m) & (c <= hi - margin_m)
    return within


def _inward(plane: Plane, x: np.ndarray, votes: np.ndarray, settings: ShellSettings
            ) -> tuple[np.ndarray, float, float] | None:
    """(normal, offset) of the plane turned to the side that holds the scene's Gaussians x [N, 3], and the share
    of their votes [N] (footprint areas, planes.votes_and_radii) on the other side, both among the Gaussians that
    lie within the plane's own extent: its members' 1st to 99th percentile along its two in-plane axes, less 2
    distance_m at each edge (the Gaussians of a surface meeting it there scatter across it). None when both sides
    hold more than boundary_share (not a boundary). Shares of area, not of count: photos leave many small floaters
    a few cm behind a surface, which must not unmake it. With nothing off the plane within its extent, the side of
    the scene's median Gaussian is inside."""
    d = plane.distance(x)
    within = _within_extent(plane, x, 2 * settings.distance_m)
    w, dw = votes[within], d[within]
    total = max(float(w.sum()), 1e-300)
    above = float(w[dw > settings.distance_m].sum()) / total
    below = float(w[dw < -settings.distance_m].sum()) / total
    if min(above, below) > settings.boundary_share:
        return None
    if above == below == 0.0:
        above = float(np.median(d) > 0)
    return (plane.normal, plane.offset, below) if above >= below else (-plane.normal, -plane.offset, above)


def build_shell(x: np.ndarray, planes: list[Plane], settings: ShellSettings,
                areas_m2: np.ndarray | None = None) -> list[Surface]:
    """The shell's surfaces (floor, ceiling, walls; module docstring) from the planes of Gaussians x [N, 3] m whose
    footprints are areas_m2 [N] m^2 (planes.footprint_areas_m2; None: points of equal weight).
    Raises ValueError naming what is missing when no floor or fewer than two walls are found."""
    votes, radii = votes_and_radii(areas_m2, len(x))
    half = radii / np.sqrt(2.0)          # half the side of each footprint's square [m]
    cos_class = np.cos(np.radians(settings.class_deg))
    floors, ceilings, walls = [], [], []
    z_lo, z_hi = weighted_quantile(x[:, 2], votes, [0.01, 0.99])
    boundaries = [(plane, *turned[:2]) for plane in planes if (turned := _inward(plane, x, votes, settings)) is not None]
    for plane, normal, offset in _innermost(x, votes, boundaries, settings):
        vertical_share = abs(normal @ UP)
        if vertical_share >= cos_class:
            (floors if normal[2] > 0 else ceilings).append((plane, normal, offset))
        elif vertical_share <= np.sin(np.radians(settings.class_deg)):
            w = votes[plane.members]
            z0, z1 = weighted_quantile(x[plane.members, 2], w, [0.02, 0.98])
            along = np.cross(UP, normal)
            s0, s1 = weighted_quantile(x[plane.members] @ along, w, [0.01, 0.99])
            if z1 - z0 >= settings.min_wall_height_share * (z_hi - z_lo) and s1 - s0 >= settings.min_wall_length_m:
                walls.append((plane, normal, offset))
    if not floors:
        raise ValueError("no floor: no horizontal plane with the scene's Gaussians above it")
    walls = _join_coplanar(x, votes, walls, settings)
    if len(walls) < 2:
        raise ValueError(f"{len(walls)} wall(s) found: a room needs vertical planes on at least two sides")
    floor_plane = max(floors, key=lambda f: votes[f[0].members].sum())
    floor = _snapped(x, votes, "floor", floor_plane[0].members, floor_plane[1], settings)
    wall_surfaces = [_snapped(x, votes, f"wall_{k:02d}", w[0].members, w[1], settings) for k, w in enumerate(walls)]
    on_walls = np.concatenate([w.members for w in wall_surfaces])
    top = _top_edge(x[on_walls, 2], votes[on_walls], half[on_walls], settings.cell_m)
    # ceiling candidates: horizontal boundaries with the Gaussians below, at or above the walls' top
    near_top = [c for c in ceilings if -c[2] >= top - 3 * settings.distance_m - 0.3]
    if near_top:
        plane, normal, _ = max(near_top, key=lambda c: votes[c[0].members].sum())
        ceiling = _snapped(x, votes, "ceiling", plane.members, normal, settings)
    else:
        ceiling = Surface("ceiling", "ceiling", -UP.copy(), -top, np.zeros(0, np.int64), float("nan"), inferred=True)
    corners = _wall_extents(x, votes, half, wall_surfaces, floor, ceiling, settings)
    polygon = room_outline(wall_surfaces, corners)
    for flat in (floor, ceiling):
        _flat_extent(flat, polygon, settings)
    return [floor, ceiling, *wall_surfaces]


def _top_edge(z: np.ndarray, votes: np.ndarray, half: np.ndarray, bin_m: float) -> float:
    """Height [m] of the walls' top edge from their Gaussians' heights z [N] m, votes [N] m^2 and footprint half
    sides half [N] m: where the walls' area per height (each footprint spread evenly over z +- half, in bins of
    bin_m) falls, above its highest bin at the median level, to half that level (the edge of a blurred step:
    photos blur the top edge, a few floaters above it do not move it)."""
    spread = np.linspace(-1.0, 1.0, 9)                          # nine heights per footprint: bins of >= 2 half / 8
    zz = (z[:, None] + half[:, None] * spread).ravel()
    edges = np.arange(zz.min(), zz.max() + 2 * bin_m, bin_m)
    area, _ = np.histogram(zz, edges, weights=np.repeat(votes / len(spread), len(spread)))
    level = float(np.median(area[area > 0]))
    k = int(np.flatnonzero(area >= level)[-1])
    while k + 1 < len(area) and area[k + 1] >= 0.5 * level:
        k += 1
    centres = 0.5 * (edges[:-1] + edges[1:])
    if k + 1 == len(area):
        return float(edges[-1])
    # linear between the last bin at or above half the level and the next one
    return float(centres[k] + bin_m * (area[k] - 0.5 * level) / (area[k] - area[k + 1]))


def _innermost(x, votes, boundaries, settings: ShellSettings):
    """The boundaries (plane, inward normal, offset) less those lying behind a larger one: most of their members
    farther than distance_m behind its plane, within its extent (less 2 distance_m at the edges). Photos leave
    layers of Gaussians behind a wall (what the wall's texture or a window's reflection showed them); each is
    a boundary too, with nothing behind it, but outside the room."""
    kept = []
    for plane, normal, offset in sorted(boundaries, key=lambda b: -votes[b[0].members].sum()):
        m = plane.members
        behind = any(np.mean(((x[m] @ n2 - o2) < -settings.distance_m) & _within_extent(p2, x, 2 * settings.distance_m, x[m]))
                     > 0.5 for p2, n2, o2 in kept)
        if not behind:
            kept.append((plane, normal, offset))
    return kept


def _join_coplanar(x, votes, walls, settings: ShellSettings):
    """Walls whose planes agree (normals within snap_deg, offsets within 2 distance_m) joined into one."""
    out: list[tuple[Plane, np.ndarray, float]] = []
    cos_same = np.cos(np.radians(max(settings.snap_deg, 5.0)))
    for plane, normal, offset in sorted(walls, key=lambda w: -votes[w[0].members].sum()):
        for k, (p2, n2, o2) in enumerate(out):
            if normal @ n2 >= cos_same and abs(offset - o2) <= 2 * settings.distance_m:
                members = np.union1d(p2.members, plane.members)
                n_fit, o_fit, rms = fit_plane(x[members], votes[members])
                if n_fit @ n2 < 0:
                    n_fit, o_fit = -n_fit, -o_fit
                out[k] = (Plane(n_fit, o_fit, members, rms), n_fit, o_fit)
                break
        else:
            out.append((plane, normal, offset))
    return out


def _snapped(x, votes, name: str, members: np.ndarray, normal: np.ndarray, settings: ShellSettings) -> Surface:
    """A surface on the members' plane (normal into the room), snapped to horizontal (floor, ceiling) or vertical
    (wall) when within snap_deg; the offset the members' area-weighted median distance along the (snapped) normal."""
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
    offset = float(weighted_quantile(x[members] @ normal, votes[members], 0.5))
    return Surface(name, kind, normal, offset, members, tilt)


@dataclass
class Corner:
    """Where two walls meet: wall indices a, b (into the wall list), which end of each (0: the start along its u,
    1: the end) and the point [2] in xy [m]."""
    a: int
    end_a: int
    b: int
    end_b: int
    xy: np.ndarray


def _wall_extents(x, votes, half, walls: list[Surface], floor: Surface, ceiling: Surface,
                  settings: ShellSettings) -> list[Corner]:
    """Each wall's extent (ends met with the neighbouring walls, floor to ceiling) and occupancy grid; returns the
    corners where walls were met."""
    from scipy import ndimage

    z0 = _height_at(floor)
    z1 = _height_at(ceiling)
    alongs, ends = [], []
    for wall in walls:
        along = np.cross(UP, wall.normal)
        along /= np.linalg.norm(along)
        s = x[wall.members] @ along
        w, h = votes[wall.members], half[wall.members]
        alongs.append(along)
        ends.append([float(weighted_quantile(s - h, w, 0.005)), float(weighted_quantile(s + h, w, 0.995))])
    corners = _corners(walls, alongs, ends, settings.corner_m)
    for c in corners:
        ends[c.a][c.end_a] = float(c.xy @ alongs[c.a][:2])
        ends[c.b][c.end_b] = float(c.xy @ alongs[c.b][:2])
    for wall, along, (s0, s1) in zip(walls, alongs, ends):
        if s1 < s0:         # a wall shorter than the corners moved onto it: its own ends in the other order
            s0, s1 = s1, s0
        base = wall.offset * wall.normal
        wall.u, wall.v = along, UP.copy()
        wall.origin = base + s0 * along + z0 * UP - (base @ UP) * UP
        wall.cell_m = settings.cell_m
        shape = (max(1, int(round((s1 - s0) / settings.cell_m))), max(1, int(round((z1 - z0) / settings.cell_m))))
        near = np.abs(x @ wall.normal - wall.offset) <= settings.distance_m     # every Gaussian on the wall counts
        closed = _closed(_cells(x[near], wall, shape, half[near]), int(round(settings.close_m / settings.cell_m)))
        # an opening is one a min_opening_m square fits in (a door, a window); narrower gaps, such as the strips
        # along the floor behind the furniture and under the ceiling that photos do not see, are wall
        k = max(1, int(round(settings.min_opening_m / settings.cell_m)))
        wall.occupied = ~ndimage.binary_opening(~closed, np.ones((k, k), bool))
    return corners


def _corners(walls: list[Surface], alongs: list[np.ndarray], ends: list[list[float]], corner_m: float) -> list[Corner]:
    """Corners of walls that meet: for every two walls more than 30 degrees apart, the line where their planes meet
    is a corner candidate at an end of each that lies within corner_m of it, costing the two distances; the
    cheapest candidates are taken first, each wall end and each pair of walls at most once (so that a wall's
    end takes its own neighbour, not a wall beyond it whose plane passes nearby)."""
    candidates = []
    for a in range(len(walls)):
        for b in range(a + 1, len(walls)):
            if abs(walls[a].normal @ walls[b].normal) > np.cos(np.radians(30)):
                continue
            xy = _meeting_point(walls[a], walls[b])[:2]
            sa, sb = float(xy @ alongs[a][:2]), float(xy @ alongs[b][:2])
            for ka in (0, 1):
                for kb in (0, 1):
                    da, db = abs(sa - ends[a][ka]), abs(sb - ends[b][kb])
                    if da <= corner_m and db <= corner_m:
                        candidates.append((da + db, a, ka, b, kb, xy))
    taken, joined, out = set(), set(), []
    for _, a, ka, b, kb, xy in sorted(candidates, key=lambda c: c[0]):
        if (a, ka) in taken or (b, kb) in taken or (a, b) in joined:
            continue
        taken |= {(a, ka), (b, kb)}
        joined.add((a, b))
        out.append(Corner(a, ka, b, kb, xy))
    return out


def _height_at(flat: Surface) -> float:
    """Height [m] of a horizontal surface (offset along its +-z normal)."""
    return float(flat.offset * np.sign(flat.normal[2]))


def _meeting_point(a: Surface, b: Surface) -> np.ndarray:
    """[3] point at z = 0 on the line where vertical walls a and b meet."""
    m = np.array([a.normal[:2], b.normal[:2]])
    xy = np.linalg.solve(m, np.array([a.offset, b.offset]))
    return np.array([xy[0], xy[1], 0.0])


def room_outline(walls: list[Surface], corners: list[Corner]) -> np.ndarray:
    """[K, 2] the room's outline in xy [m]: the walls in order around the room, from one corner (where two walls'
    planes meet) to the next; a wall's end met by no other wall goes straight on to the nearest end of a wall not
    yet taken (a gap where no wall was found, such as an open side). The walls' extents (origin, u, size) must be
    set. When that walk does not give a simple polygon through every wall, the walls' ends ordered by angle about
    their centroid (right for a room every wall of which is seen from its centre)."""
    ends = [[(w.origin + s * w.u)[:2] for s in (0.0, w.size_m[0])] for w in walls]
    partner, at = {}, {}
    for c in corners:
        partner[(c.a, c.end_a)], partner[(c.b, c.end_b)] = (c.b, c.end_b), (c.a, c.end_a)
        at[(c.a, c.end_a)] = at[(c.b, c.end_b)] = np.asarray(c.xy, float)

    def point(w, k):
        return at.get((w, k), ends[w][k])

    points, visited = [point(0, 0)], set()
    wall, entry = 0, 0
    while True:
        visited.add(wall)
        exit_end = 1 - entry
        points.append(point(wall, exit_end))
        if (wall, exit_end) in partner:
            wall, entry = partner[(wall, exit_end)]
            if wall in visited:
                break
            continue
        free = [(np.linalg.norm(point(w, k) - points[-1]), w, k) for w in range(len(walls)) if w not in visited
                for k in (0, 1)]
        if not free:
            break
        _, wall, entry = min(free, key=lambda f: f[0])
        points.append(point(wall, entry))
    polygon = _without_repeats(np.array(points))
    if len(visited) == len(walls) and len(polygon) >= 3 and _is_simple(polygon):
        return polygon
    return _angle_sorted_ends(walls)


def _without_repeats(points: np.ndarray, tol_m: float = 1e-6) -> np.ndarray:
    """The polygon's vertices [K, 2] less each one that repeats the one before (and a last one repeating the first)."""
    keep = [p for k, p in enumerate(points) if k == 0 or np.linalg.norm(p - points[k - 1]) > tol_m]
    if len(keep) > 1 and np.linalg.norm(keep[-1] - keep[0]) <= tol_m:
        keep.pop()
    return np.array(keep)


def _is_simple(polygon: np.ndarray) -> bool:
    """Whether the closed polygon [K, 2] has no two edges that cross (edges sharing a vertex aside)."""
    k = len(polygon)
    edges = [(polygon[i], polygon[(i + 1) % k]) for i in range(k)]

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    for i in range(k):
        for j in range(i + 1, k):
            if j == i + 1 or (i == 0 and j == k - 1):
                continue
            (p, q), (r, s) = edges[i], edges[j]
            if cross(p, q, r) * cross(p, q, s) < 0 and cross(r, s, p) * cross(r, s, q) < 0:
                return False
    return True


def _angle_sorted_ends(walls: list[Surface]) -> np.ndarray:
    """[K, 2] the walls' end points in xy, ordered by angle about their centroid, near-duplicate corners joined."""
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


def _cells(x: np.ndarray, surface: Surface, shape: tuple[int, int], half: np.ndarray | None = None) -> np.ndarray:
    """[nu, nv] bool: the cells holding one of the points x [N, 3] (projected onto the surface), and with half [N]
    [m] (half the side of each one's footprint square) every cell whose centre its footprint covers."""
    rel = x - surface.origin
    a, b = rel @ surface.u / surface.cell_m, rel @ surface.v / surface.cell_m
    i, j = np.floor(a).astype(int), np.floor(b).astype(int)
    grid = np.zeros(shape, bool)

    def mark(ci, cj):
        ok = (ci >= 0) & (ci < shape[0]) & (cj >= 0) & (cj < shape[1])
        grid[ci[ok], cj[ok]] = True

    mark(i, j)
    h = np.zeros(len(x)) if half is None else np.asarray(half, float) / surface.cell_m
    big = h >= 0.5                       # smaller footprints reach no other cell's centre
    if big.any():
        reach = int(np.ceil(h[big].max()))
        for di in range(-reach, reach + 1):
            for dj in range(-reach, reach + 1):
                ci, cj = i[big] + di, j[big] + dj
                cover = (np.abs(ci + 0.5 - a[big]) <= h[big]) & (np.abs(cj + 0.5 - b[big]) <= h[big])
                mark(ci[cover], cj[cover])
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
