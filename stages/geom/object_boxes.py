"""Objects as boxes: the object segments of `rfir structure` (Gaussians off the room's shell, joined by DBSCAN)
turned into boxes whose faces the room model traces as planar patches (docs/physics.md 8.10), for furniture.

A segment's boxes share one yaw about z: the yaw of the smallest rectangle holding its Gaussians' horizontal
positions (their 0.5th to 99.5th area-weighted percentiles along the rectangle's sides, searched over 0-90 degrees),
snapped to the room's wall directions when within `box_yaw_snap_deg` of one (a row of desks stands square to the
walls; a chair turned by 20 degrees keeps its own).

In that frame the segment's Gaussians mark a voxel grid of `box_cell_m`: each marks the voxels its footprint
reaches (its in-plane extent along each axis, at most two voxels). A box's *fill* is the smallest, over its three
axis projections (top, front and side views), of the share of the view that marked voxels cover and of the mean
share they cover of its four corners (a quarter of the view's length along each side), gaps of a voxel and holes in
the view filled first (photo Gaussians cover a face sparsely). A box whose faces were seen fills each view, corners
included (a view is covered by the face that looks at it, or by the faces around it); a sphere covers pi / 4 of
each view and little of its corners; a desk's bounding box little of its side views (its top's edge and four legs).
A part whose fill reaches `box_fill` is a box; otherwise it is cut in two along one of its axes at the voxel
boundary where the area-weighted mean fill of the two parts' tight boxes is highest (a part with fewer than
`object_min_points` Gaussians counting as fill 0: it will be left out), when that raises the fill by at least
`box_split_gain`, and each part is judged again, at most `box_max_depth` cuts deep. A part's tight box leaves out
end slices that hold at most TRIM_SHARE of its Gaussians (strays), and a box one voxel across in two of its axes (a
stick: a slice of whatever it was cut from) is left out. So a desk becomes its top slab and its legs (thin posts
where the photos show them, else left free), a row of desks joined by their chairs is cut into pieces, a floater is
cut off. A segment whose boxes explain less than `box_min_share` of its Gaussians' area is not box-like (a round
blob: its cuts leave pieces of the same fill) and stays free Gaussians.

A box's faces are placed on its Gaussians: along each axis its extent is the 1st to 99th area-weighted percentile
of the Gaussians' footprints, then each end moves to the area-weighted median position of the Gaussians facing
along that axis (normal within `normal_deg`) within 2 `distance_m` of it on its own half (the face's Gaussians
scatter a few centimetres about it). A box thinner than 4 `distance_m` along an axis (a desk's top, seen from one
side) is a plate: `distance_m` thick about its Gaussians' median. A box whose bottom lies within `box_floor_m` of
the floor stands on it. Faces lying on a shell surface and facing it (the bottom on the floor, a back against a
wall) are left out, as `mesh-gaussians --preset room` leaves out a mesh's contact faces; the others are tiled
with flat surfels, at most min(spacing_m, the box's largest side / `box_cells`) apart, as that preset tiles
furniture.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .from_mesh import gaussians_from_mesh
from .planes import weighted_quantile

MAX_REACH_CELLS = 2          # a footprint marks voxels at most this many cells from its centre's: a blurry floater
#                              does not fill a view by itself
YAW_COARSE_DEG = 1.0         # the yaw search: every degree over 0-90, then every YAW_FINE_DEG about the best
YAW_FINE_DEG = 0.1
TRIM_SHARE = 0.01            # a part's box leaves out end slices holding at most this share of its Gaussians (strays)


@dataclass
class BoxSettings:
    """Thresholds of the object boxes (configs/geom.toml [geom.structure]): objects "boxes" or "keep" (the
    segments as Gaussian blobs); lengths in metres, angles in degrees, box_fill and box_split_gain shares."""
    objects: str = "boxes"
    box_cell_m: float = 0.05
    box_fill: float = 0.8
    box_split_gain: float = 0.05
    box_min_share: float = 0.5
    box_max_depth: int = 8
    box_yaw_snap_deg: float = 5.0
    box_floor_m: float = 0.1
    box_cells: int = 12


@dataclass
class Box:
    """An object box: name (object_NN), centre [3] m, size_m [3] along u, v and up [m], yaw_deg (u's angle from x
    about z), members [M] (indices of the Gaussians it explains), fill (module docstring), on_floor (its bottom
    on the floor: no bottom face)."""
    name: str
    centre: np.ndarray
    size_m: np.ndarray
    yaw_deg: float
    members: np.ndarray
    fill: float
    on_floor: bool

    @property
    def axes(self) -> np.ndarray:
        """[3, 3] rows: the box's unit axes u, v (horizontal) and up."""
        c, s = np.cos(np.radians(self.yaw_deg)), np.sin(np.radians(self.yaw_deg))
        return np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])

    def faces(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """The six faces as (corner [3], side_a [3], side_b [3]) with side_a x side_b along the outward normal."""
        axes = self.axes
        half = 0.5 * self.size_m
        out = []
        for k in range(3):
            a, b = (k + 1) % 3, (k + 2) % 3
            for sign in (-1.0, 1.0):
                centre = self.centre + sign * half[k] * axes[k]
                side_a, side_b = self.size_m[a] * axes[a], self.size_m[b] * axes[b]
                if sign < 0:                   # outward along -axes[k]: swap the sides' order
                    side_a, side_b = side_b, side_a
                out.append((centre - 0.5 * side_a - 0.5 * side_b, side_a, side_b))
        return out


def settings_errors(s) -> list[str]:
    """One line per bad box setting of s (a settings object with BoxSettings' fields)."""
    errors = []
    if s.objects not in ("boxes", "keep"):
        errors.append(f"geom.structure.objects must be \"boxes\" or \"keep\", got {s.objects!r}")
    for name in ("box_cell_m", "box_fill", "box_floor_m", "box_min_share"):
        if not getattr(s, name) > 0:
            errors.append(f"geom.structure.{name} must be positive, got {getattr(s, name)}")
    if not 0 < s.box_fill <= 1:
        errors.append(f"geom.structure.box_fill must be in (0, 1], got {s.box_fill}")
    for name in ("box_max_depth", "box_cells"):
        if int(getattr(s, name)) != getattr(s, name) or getattr(s, name) < 1:
            errors.append(f"geom.structure.{name} must be a positive whole number, got {getattr(s, name)}")
    return errors


def find_boxes(x: np.ndarray, normals: np.ndarray, votes: np.ndarray, half: np.ndarray, piece: np.ndarray,
               floor_z: float, wall_normals: list[np.ndarray], settings, *, distance_m: float, normal_deg: float,
               min_points: int) -> list[Box]:
    """The boxes of the object segments (module docstring).

    x [N, 3] m, normals [N, 3] unit (sign-free), votes [N] m^2 (footprint areas, planes.votes_and_radii), half [N]
    m (half the side of each footprint's square), piece [N] int: each Gaussian's segment (-1: none); floor_z [m];
    wall_normals: the shell walls' unit normals [3] (their yaws are the room's directions); settings: BoxSettings'
    fields. Boxes are named object_00, ... in segment order; a Gaussian is a member of at most one box, and those
    of no box are the segments' Gaussians left free."""
    wall_yaws = [float(np.degrees(np.arctan2(n[1], n[0])) % 90.0) for n in wall_normals]
    boxes: list[Box] = []
    for seg in np.unique(piece[piece >= 0]):
        idx = np.flatnonzero(piece == seg)
        yaw = segment_yaw(x[idx, :2], votes[idx], wall_yaws, settings.box_yaw_snap_deg)
        c, s = np.cos(np.radians(yaw)), np.sin(np.radians(yaw))
        axes = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
        q = x[idx] @ axes.T                                       # [n, 3] along u, v, up
        along = np.abs(normals[idx] @ axes.T)                     # [n, 3] |cos| of each normal with each axis
        ext = half[idx, None] * np.sqrt(np.clip(1.0 - along ** 2, 0.0, 1.0))   # footprint's half extent per axis
        parts = _parts(q, ext, votes[idx], settings, min_points)
        explained = np.zeros(len(idx), bool)
        for part, _ in parts:
            explained |= part
        if votes[idx][explained].sum() < settings.box_min_share * votes[idx].sum():
            continue                           # not box-like: the segment stays free Gaussians
        for part, fill in parts:
            members = idx[part]
            lo, hi = _extent(q[part], ext[part], along[part], votes[members], distance_m, normal_deg)
            on_floor = bool(lo[2] - floor_z <= settings.box_floor_m)
            if on_floor:
                lo[2] = floor_z
            centre = axes.T @ (0.5 * (lo + hi))
            boxes.append(Box(f"object_{len(boxes):02d}", centre, hi - lo, yaw, members, fill, on_floor))
    return boxes


def segment_yaw(xy: np.ndarray, weights: np.ndarray, wall_yaws: list[float], snap_deg: float) -> float:
    """Yaw [deg, 0-90] of the smallest rectangle about the points xy [n, 2] (sides at their 0.5th and 99.5th
    weighted percentiles), the nearest of wall_yaws [deg] instead when within snap_deg of it (modulo 90)."""
    def area(yaw_deg):
        t = np.radians(yaw_deg)
        u = xy @ np.array([np.cos(t), np.sin(t)])
        v = xy @ np.array([-np.sin(t), np.cos(t)])
        (u0, u1), (v0, v1) = weighted_quantile(u, weights, [0.005, 0.995]), weighted_quantile(v, weights, [0.005, 0.995])
        return (u1 - u0) * (v1 - v0)

    coarse = np.arange(0.0, 90.0, YAW_COARSE_DEG)
    best = coarse[int(np.argmin([area(a) for a in coarse]))]
    fine = best + np.arange(-YAW_COARSE_DEG, YAW_COARSE_DEG + 1e-9, YAW_FINE_DEG)
    own = float(fine[int(np.argmin([area(a) for a in fine]))] % 90.0)
    for wall in wall_yaws:
        gap = (own - wall + 45.0) % 90.0 - 45.0
        if abs(gap) <= snap_deg:
            return float(wall)
    return own


def _parts(q: np.ndarray, ext: np.ndarray, votes: np.ndarray, settings, min_points: int) -> list[tuple[np.ndarray, float]]:
    """The box-like parts of one segment: ([M] bool over its Gaussians, fill) each (module docstring); q [n, 3] m
    in the segment's frame, ext [n, 3] m each footprint's half extent along its axes, votes [n] m^2."""
    cell = settings.box_cell_m
    ext = np.minimum(ext, MAX_REACH_CELLS * cell)
    origin = (q - ext).min(0)
    first = np.floor((q - ext - origin) / cell).astype(int)
    last = np.floor((q + ext - origin) / cell).astype(int)
    centre = np.clip(np.floor((q - origin) / cell).astype(int), first, last)
    shape = tuple(last.max(0) + 1)
    grid = np.zeros(shape, bool)
    span = last - first
    for di in range(2 * MAX_REACH_CELLS + 1):
        for dj in range(2 * MAX_REACH_CELLS + 1):
            for dk in range(2 * MAX_REACH_CELLS + 1):
                ok = (span[:, 0] >= di) & (span[:, 1] >= dj) & (span[:, 2] >= dk)
                grid[first[ok, 0] + di, first[ok, 1] + dj, first[ok, 2] + dk] = True
    weight = np.zeros(shape)
    count = np.zeros(shape, np.int64)
    np.add.at(weight, tuple(centre.T), votes)
    np.add.at(count, tuple(centre.T), 1)
    judge = _Judge(grid, weight, count, min_points)
    found = judge.split((np.zeros(3, int), np.array(shape)), settings, 0)
    out = []
    for lo, hi, fill in found:
        inside = ((centre >= lo) & (centre < hi)).all(1)
        out.append((inside, fill))
    return out


class _Judge:
    """The guillotine cuts of one segment's voxel grid (module docstring): grid [I, J, K] bool marked voxels,
    weight [I, J, K] m^2 and count [I, J, K] of the Gaussians centred in each voxel."""

    def __init__(self, grid: np.ndarray, weight: np.ndarray, count: np.ndarray, min_points: int):
        self.grid, self.weight, self.count, self.min_points = grid, weight, count, min_points

    def tight(self, lo, hi):
        """(lo [3], hi [3]) of the voxels with Gaussians centred in them within [lo, hi), or None when none."""
        sub = self.count[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]] > 0
        if not sub.any():
            return None
        counts = self.count[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
        allowed = TRIM_SHARE * counts.sum()
        new_lo, new_hi = lo.copy(), lo.copy()
        for axis in range(3):
            rows = counts.sum(axis=tuple(a for a in range(3) if a != axis))
            cum = np.cumsum(rows)
            first = int(np.searchsorted(cum, allowed, side="right"))          # leading slices under the share
            last = int(np.searchsorted(cum, cum[-1] - allowed, side="left"))  # ... and trailing ones: dropped
            first, last = min(first, int(np.flatnonzero(rows)[-1])), max(last, first)
            new_lo[axis] += first
            new_hi[axis] += last + 1
        return new_lo, new_hi

    def fill(self, lo, hi) -> float:
        """The smallest share of the box's three axis projections that marked voxels cover, each projection's
        gaps of a voxel and holes filled (photo Gaussians cover a face sparsely; a sphere's disc has neither)."""
        from scipy import ndimage

        sub = self.grid[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
        shares = []
        for a in range(3):
            view = np.pad(sub.any(axis=a), 2)
            view = ndimage.binary_fill_holes(ndimage.binary_closing(view, np.ones((3, 3), bool)))[2:-2, 2:-2]
            ci, cj = max(1, view.shape[0] // 4), max(1, view.shape[1] // 4)
            corners = np.mean([view[:ci, :cj].mean(), view[:ci, -cj:].mean(), view[-ci:, :cj].mean(),
                               view[-ci:, -cj:].mean()])
            shares.append(min(view.mean(), corners))
        return float(min(shares))

    def mass(self, lo, hi) -> tuple[float, int]:
        sl = np.s_[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]]
        return float(self.weight[sl].sum()), int(self.count[sl].sum())

    def scored(self, lo, hi) -> tuple[float, float, tuple | None]:
        """(weight [m^2], fill (0 when too few Gaussians to be kept), tight box) of the part [lo, hi)."""
        box = self.tight(lo, hi)
        if box is None:
            return 0.0, 0.0, None
        w, n = self.mass(*box)
        return w, (self.fill(*box) if n >= self.min_points else 0.0), box

    def split(self, bounds, settings, depth: int) -> list[tuple[np.ndarray, np.ndarray, float]]:
        """The box-like parts [(lo, hi, fill)] of the part within bounds (lo, hi) voxel indices."""
        weight, fill, box = self.scored(*bounds)
        if box is None or fill == 0.0:
            return []
        if fill >= settings.box_fill:
            # a stick (one voxel across in two of its axes) is a slice of whatever it was cut from: left free
            return [(box[0], box[1], fill)] if (box[1] - box[0] >= 2).sum() >= 2 else []
        if depth >= settings.box_max_depth:
            return []
        lo, hi = box
        best, best_score = None, fill + settings.box_split_gain
        for axis in range(3):
            for cut in range(lo[axis] + 1, hi[axis]):
                hi_a, lo_b = hi.copy(), lo.copy()
                hi_a[axis], lo_b[axis] = cut, cut
                wa, fa, _ = self.scored(lo, hi_a)
                wb, fb, _ = self.scored(lo_b, hi)
                if wa + wb <= 0:
                    continue
                score = (wa * fa + wb * fb) / (wa + wb)
                if score >= best_score:
                    best, best_score = ((lo, hi_a), (lo_b, hi)), score
        if best is None:
            return []
        return self.split(best[0], settings, depth + 1) + self.split(best[1], settings, depth + 1)


def _extent(q: np.ndarray, ext: np.ndarray, along: np.ndarray, votes: np.ndarray, distance_m: float,
            normal_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """(lo [3], hi [3]) of a box in its frame [m] from its Gaussians q [m, 3], their footprints' half extents ext
    [m, 3] and |cos| of their normals with the axes along [m, 3] (module docstring)."""
    lo, hi = np.zeros(3), np.zeros(3)
    facing_cos = np.cos(np.radians(normal_deg))
    for a in range(3):
        lo0 = float(weighted_quantile(q[:, a] - ext[:, a], votes, 0.01))
        hi0 = float(weighted_quantile(q[:, a] + ext[:, a], votes, 0.99))
        if hi0 - lo0 < 4 * distance_m:           # a plate: seen from one side, its thickness is not measured
            mid = float(weighted_quantile(q[:, a], votes, 0.5))
            lo[a], hi[a] = mid - 0.5 * distance_m, mid + 0.5 * distance_m
            continue
        mid = 0.5 * (lo0 + hi0)
        facing = along[:, a] >= facing_cos
        ends = []
        for end, side in ((lo0, q[:, a] < mid), (hi0, q[:, a] > mid)):
            face = facing & side & (np.abs(q[:, a] - end) <= 2 * distance_m)
            ends.append(float(weighted_quantile(q[face, a], votes[face], 0.5)) if face.sum() >= 3 else end)
        lo[a], hi[a] = ends
    return lo, hi


def box_fields(boxes: list[Box], shell: list, spacing_m: float, box_cells: int, distance_m: float,
               first_label: int, colors: np.ndarray | None) -> tuple[dict, int]:
    """(scene fields of the surfels tiling the boxes' faces, labels first_label + box index; number of faces left
    out as lying on a shell surface and facing it). shell: the shell's Surfaces (floor, ceiling, walls); colors
    [N, 3] of the input Gaussians (None: no colours), each box getting its members' median."""

    parts, dropped = [], 0
    for k, box in enumerate(boxes):
        verts, faces = [], []
        for corner, side_a, side_b in box.faces():
            normal = np.cross(side_a, side_b)
            normal /= np.linalg.norm(normal)
            middle = corner + 0.5 * side_a + 0.5 * side_b
            if any(normal @ s.normal < -0.99 and abs(middle @ s.normal - s.offset) <= distance_m for s in shell):
                dropped += 1
                continue
            base = 4 * len(verts)
            verts.append(np.array([corner, corner + side_a, corner + side_a + side_b, corner + side_b]))
            faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
        if not faces:
            continue
        spacing = min(spacing_m, float(box.size_m.max()) / box_cells)
        fields = gaussians_from_mesh(np.concatenate(verts), np.asarray(faces), spacing,
                                     labels=np.full(len(faces), first_label + k), rectangles=True)
        if colors is not None:
            fields["gaussians/colors"] = np.broadcast_to(np.median(colors[box.members], axis=0),
                                                         (len(fields["gaussians/means"]), 3)).copy()
        parts.append(fields)
    if not parts:
        return {}, dropped
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}, dropped


def box_record(box: Box) -> dict:
    """A box's summary for provenance (lengths in metres, angles in degrees)."""
    return {"name": box.name, "centre_m": [round(float(v), 3) for v in box.centre],
            "size_m": [round(float(v), 3) for v in box.size_m], "yaw_deg": round(box.yaw_deg, 2),
            "fill": round(box.fill, 3), "gaussians": int(len(box.members)), "on_floor": box.on_floor}
