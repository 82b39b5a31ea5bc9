"""Planes in a cloud of Gaussians: robust plane fits (Open3D's RANSAC `segment_plane`), each plane split into its
connected pieces (Open3D's DBSCAN), for `rfir structure` (room_shell.py builds the room from them).

Photo Gaussians scatter by a few centimetres about their surface and their normals by some degrees, so a
Gaussian belongs to a plane when it lies within `distance_m` of it *and* its normal is within `normal_deg` of the
plane's: a desk's side does not join the wall behind it, a floor Gaussian with a tilted normal still joins the
floor. The largest plane is taken first, its members removed, and so on; pieces of a plane that are not
connected (the tops of a row of desks at one height) become planes of their own.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

RANSAC_ITERATIONS = 1000     # a plane holding a tenth of the points is missed with probability (1 - 0.1^3)^1000 ~ 37 %;
RANSAC_TRIES = 3             # ... so a failed search is tried again with other samples before giving up


@dataclass
class Plane:
    """One planar piece: unit normal [3], offset [m] (normal . x = offset on the plane), members [M] indices into
    the cloud, rms_m: RMS distance of the members from the plane [m]."""
    normal: np.ndarray
    offset: float
    members: np.ndarray
    rms_m: float

    def distance(self, x: np.ndarray) -> np.ndarray:
        """Signed distances [N] m of points x [N, 3] from the plane (positive on the normal's side)."""
        return x @ self.normal - self.offset


def fit_plane(x: np.ndarray, weights: np.ndarray | None = None) -> tuple[np.ndarray, float, float]:
    """Least-squares plane of points x [N, 3] (weights [N] optional): (unit normal [3], offset [m], RMS distance [m]).
    The normal is the covariance's smallest eigenvector, its sign chosen with a non-negative largest component
    so that the result does not depend on the points' order."""
    w = np.ones(len(x)) if weights is None else np.asarray(weights, float)
    centre = (w[:, None] * x).sum(0) / w.sum()
    d = x - centre
    cov = (w[:, None, None] * d[:, :, None] * d[:, None, :]).sum(0) / w.sum()
    ev, evec = np.linalg.eigh(cov)
    normal = evec[:, 0]
    if normal[np.argmax(np.abs(normal))] < 0:
        normal = -normal
    return normal, float(normal @ centre), float(np.sqrt(max(ev[0], 0.0)))


def connected_pieces(x: np.ndarray, eps_m: float, min_points: int) -> np.ndarray:
    """Piece of each point [N] int (-1: in no piece of min_points or more) by DBSCAN on positions x [N, 3] m
    (neighbours within eps_m; Open3D's cluster_dbscan)."""
    import open3d as o3d

    if len(x) == 0:
        return np.zeros(0, np.int64)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(x, dtype=np.float64)))
    piece = np.asarray(cloud.cluster_dbscan(eps=eps_m, min_points=min(4, len(x)), print_progress=False), np.int64)
    if (piece >= 0).any():
        sizes = np.bincount(piece[piece >= 0])
        piece = np.where((piece >= 0) & (sizes[np.maximum(piece, 0)] >= min_points), piece, -1)
    return piece


def find_planes(x: np.ndarray, normals: np.ndarray, *, distance_m: float, normal_deg: float, min_points: int,
                piece_eps_m: float, max_planes: int, seed: int = 0, progress=None) -> list[Plane]:
    """Planes of points x [N, 3] m with normals [N, 3] (unit, sign-free), largest first (see the module docstring).

    distance_m: the RANSAC inlier distance and the members' largest distance from the refitted plane [m];
    normal_deg: largest angle between a member's normal and the plane's; min_points: the fewest members of a
    plane (and of each connected piece; smaller pieces are left out of every plane); piece_eps_m: DBSCAN
    neighbour distance that splits a plane into its connected pieces (at least 3 times the members' median
    nearest-neighbour distance); max_planes: the search stops there.
    Points in no plane are those in no returned Plane's members."""
    import open3d as o3d

    o3d.utility.random.seed(int(seed))
    cos_max = np.cos(np.radians(normal_deg))
    up = np.abs(normals[:, 2])
    # RANSAC counts points, not normals: among all of them a horizontal slice through the walls' Gaussians can
    # outnumber a ceiling seen in a few photos. Sampled within one family of normals at a time (level, upright,
    # the rest), a plane is one that family's points make; its members come from every remaining point.
    families = [up >= cos_max, up <= np.sin(np.radians(normal_deg))]
    families.append(~families[0] & ~families[1])
    taken = np.zeros(len(x), bool)
    planes: list[Plane] = []
    for family in families:
        failures = 0
        while len(planes) < max_planes and failures < RANSAC_TRIES:
            pool = np.flatnonzero(family & ~taken)
            if len(pool) < max(min_points, 3):
                break
            cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.ascontiguousarray(x[pool])))
            model, _ = cloud.segment_plane(distance_threshold=distance_m, ransac_n=3, num_iterations=RANSAC_ITERATIONS)
            normal = np.asarray(model[:3], float)
            normal, offset = normal / np.linalg.norm(normal), -float(model[3]) / np.linalg.norm(normal)
            remaining = np.flatnonzero(~taken)
            members = _members(x, normals, remaining, normal, offset, distance_m, cos_max)
            if len(members) >= 3:      # refit on the members (RANSAC's plane goes through three of them), take again
                normal, offset, _ = fit_plane(x[members])
                members = _members(x, normals, remaining, normal, offset, distance_m, cos_max)
            if len(members) < min_points:
                failures += 1
                continue
            failures = 0
            piece = connected_pieces(x[members], max(piece_eps_m, 3.0 * _spacing_m(x[members])), min_points)
            for p in np.unique(piece[piece >= 0]):
                idx = members[piece == p]
                n_p, o_p, rms = fit_plane(x[idx])
                planes.append(Plane(n_p, o_p, idx, rms))
            # every member leaves the pool, the small pieces too: left in, they would be found as this plane again
            taken[members] = True
            if progress is not None:
                progress.advance()
    return planes


def _spacing_m(x: np.ndarray) -> float:
    """Median distance [m] from each of the points x [N, 3] to its nearest neighbour: coarse surfels (a mesh tiled at
    tens of centimetres) are farther apart than piece_eps_m and would otherwise fall apart into single points."""
    from scipy.spatial import cKDTree

    if len(x) < 2:
        return 0.0
    return float(np.median(cKDTree(x).query(x, k=2)[0][:, 1]))


def _members(x, normals, pool, normal, offset, distance_m, cos_max) -> np.ndarray:
    """Indices of pool within distance_m of the plane whose normals agree with it to the angle of cos_max."""
    near = np.abs(x[pool] @ normal - offset) <= distance_m
    agree = np.abs(normals[pool] @ normal) >= cos_max
    return pool[near & agree]
