"""Planes in a cloud of Gaussians: robust plane fits (RANSAC whose votes are areas), each plane split into its
connected pieces (DBSCAN whose reach includes each Gaussian's footprint), for `rfir structure` (room_shell.py builds
the room from them).

Any set of Gaussians works: photo Gaussians (a few centimetres each, many per square metre), the surfels
`mesh-gaussians` lays on a mesh (walls in squares of tens of centimetres, furniture finely tiled), or a mix. So a
Gaussian votes for a plane with its footprint area (pi s1 s2 of its two largest scales, the area it stands for in
rfir_stages.geom.from_mesh and model/surfels.py), not as one point: counted as points, a row of finely tiled
desks outvotes the wall behind them. Photo Gaussians scatter by a few centimetres about their surface and their
normals by some degrees, so a Gaussian belongs to a plane when it lies within `distance_m` of it *and* its normal
is within `normal_deg` of the plane's: a desk's side does not join the wall behind it, a floor Gaussian with a
tilted normal still joins the floor. The largest plane (by area) is taken first, its members removed, and so on;
pieces of a plane that are not connected (the tops of a row of desks at one height) become planes of their own.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

RANSAC_ITERATIONS = 1000     # a plane holding a tenth of the area is missed with probability (1 - 0.1^3)^1000 ~ 37 %;
RANSAC_TRIES = 3             # ... so a failed search is tried again with other samples before giving up
# RANSAC scores its hypotheses on this many Gaussians drawn in proportion to their votes: the share of a plane's
# inliers among them estimates its share of the area (to about 1 % of the area for a plane with a tenth of it).
SCORE_SAMPLES = 4000
# The largest footprint a vote counts [m^2] (a 0.5 m square, above mesh-gaussians' coarsest surfel of 0.4 m): a
# blurry photo floater a metre across does not make a plane by itself.
VOTE_CAP_M2 = 0.25


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


def footprint_areas_m2(log_scales: np.ndarray) -> np.ndarray:
    """[N] m^2: each Gaussian's footprint pi s1 s2, s1 and s2 its two largest scales (exp of log_scales [N, 3]):
    the face-on area of a flat Gaussian, which mesh-gaussians sizes so that a tiling adds up to the mesh's area."""
    s = np.sort(np.exp(np.asarray(log_scales, float)), axis=1)
    return math.pi * s[:, 1] * s[:, 2]


def votes_and_radii(areas_m2: np.ndarray | None, n: int) -> tuple[np.ndarray, np.ndarray]:
    """([N] vote of each Gaussian [m^2], [N] reach [m]) from footprint areas [N] m^2 (None: points, one vote
    each and no reach). The vote is the area up to VOTE_CAP_M2; the reach is half the diagonal of a square of that
    area (how far the footprint extends from its centre), so footprints that touch are neighbours."""
    if areas_m2 is None:
        return np.ones(n), np.zeros(n)
    votes = np.minimum(np.asarray(areas_m2, float), VOTE_CAP_M2)
    return votes, np.sqrt(votes / 2.0)


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


def weighted_quantile(values: np.ndarray, weights: np.ndarray, q) -> np.ndarray:
    """Quantiles q (in [0, 1], a scalar or [Q]) of values [N] with weights [N] >= 0: the value below which that share
    of the weight lies (each value's weight centred on it, linear in between; equal weights give numpy's
    'hazen' percentiles)."""
    order = np.argsort(values)
    v, w = np.asarray(values, float)[order], np.asarray(weights, float)[order]
    cum = np.cumsum(w) - 0.5 * w
    return np.interp(np.asarray(q, float) * w.sum(), cum, v)


def connected_pieces(x: np.ndarray, eps_m: float, min_points: int, *, radii: np.ndarray | None = None,
                     weights: np.ndarray | None = None, min_weight: float = math.inf) -> np.ndarray:
    """Piece of each point [N] int (-1: in no kept piece) by DBSCAN on positions x [N, 3] m: two points are
    neighbours when their footprints (radii [N] m about them; None: points) come within eps_m of each other, a point
    with at least 3 neighbours is a core point, pieces are the core points joined through neighbours plus the points
    next to them. A piece is kept when it has min_points points or, with weights [N], a total weight of min_weight
    (a few large surfels are a piece; a handful of stray photo Gaussians are not)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    n = len(x)
    if n == 0:
        return np.zeros(0, np.int64)
    r = np.zeros(n) if radii is None else np.asarray(radii, float)
    pairs = cKDTree(x).query_pairs(eps_m + 2.0 * float(r.max()), output_type="ndarray")
    if len(pairs):
        gap = np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=1) - r[pairs[:, 0]] - r[pairs[:, 1]]
        pairs = pairs[gap <= eps_m]
    degree = np.bincount(pairs.ravel(), minlength=n) if len(pairs) else np.zeros(n, np.int64)
    core = degree + 1 >= min(4, n)           # the point itself counts, as in Open3D's and scikit-learn's DBSCAN
    both = core[pairs[:, 0]] & core[pairs[:, 1]] if len(pairs) else np.zeros(0, bool)
    links = pairs[both]
    graph = coo_matrix((np.ones(len(links)), (links[:, 0], links[:, 1])), shape=(n, n)) if len(links) \
        else coo_matrix((n, n))
    _, component = connected_components(graph, directed=False)
    piece = np.where(core, component, -1)
    if len(pairs):                           # a border point joins the piece of a core neighbour
        border = pairs[core[pairs[:, 0]] ^ core[pairs[:, 1]]]
        inner = np.where(core[border[:, 0]], border[:, 0], border[:, 1])
        outer = np.where(core[border[:, 0]], border[:, 1], border[:, 0])
        piece[outer] = component[inner]
    kept = piece >= 0
    if kept.any():
        _, piece[kept] = np.unique(piece[kept], return_inverse=True)
        counts = np.bincount(piece[kept])
        total = np.bincount(piece[kept], weights=None if weights is None else np.asarray(weights, float)[kept])
        big = (counts >= min_points) | ((total >= min_weight) if weights is not None else False)
        piece = np.where(kept & big[np.maximum(piece, 0)], piece, -1)
    return piece


def find_planes(x: np.ndarray, normals: np.ndarray, *, distance_m: float, normal_deg: float, min_points: int,
                piece_eps_m: float, max_planes: int, areas_m2: np.ndarray | None = None, min_area_m2: float = math.inf,
                seed: int = 0, progress=None) -> list[Plane]:
    """Planes of points x [N, 3] m with normals [N, 3] (unit, sign-free), largest area first (module docstring).

    distance_m: the RANSAC inlier distance and the members' largest distance from the refitted plane [m];
    normal_deg: largest angle between a member's normal and the plane's; areas_m2 [N]: each Gaussian's footprint
    (footprint_areas_m2; None: every point one vote, no footprint); min_points, min_area_m2: a plane, and each of
    its connected pieces, needs min_points members or min_area_m2 [m^2] of their footprints (smaller pieces are
    left out of every plane); piece_eps_m: the widest gap [m] between the footprints of one piece's neighbours
    (DBSCAN on the footprints); max_planes: the search stops there.
    Points in no plane are those in no returned Plane's members."""
    rng = np.random.default_rng(seed)
    votes, radii = votes_and_radii(areas_m2, len(x))
    cos_max = np.cos(np.radians(normal_deg))
    up = np.abs(normals[:, 2])
    # RANSAC votes among all Gaussians: a horizontal slice through the walls' Gaussians can outweigh a ceiling
    # seen in a few photos. Sampled within one family of normals at a time (level, upright, the rest), a plane is
    # one that family's Gaussians make; its members come from every remaining Gaussian.
    families = [up >= cos_max, up <= np.sin(np.radians(normal_deg))]
    families.append(~families[0] & ~families[1])
    taken = np.zeros(len(x), bool)
    planes: list[Plane] = []

    def big_enough(idx: np.ndarray) -> bool:
        return len(idx) >= 3 and (len(idx) >= min_points or votes[idx].sum() >= min_area_m2)

    for family in families:
        failures = 0
        while len(planes) < max_planes and failures < RANSAC_TRIES:
            pool = np.flatnonzero(family & ~taken)
            if not big_enough(pool):
                break
            normal, offset = _ransac_plane(x, normals, votes, pool, rng, distance_m, cos_max)
            remaining = np.flatnonzero(~taken)
            members = _members(x, normals, remaining, normal, offset, distance_m, cos_max) if normal is not None \
                else np.zeros(0, np.int64)
            if len(members) >= 3:      # refit on the members (RANSAC's plane goes through three of them), take again
                normal, offset, _ = fit_plane(x[members], votes[members])
                members = _members(x, normals, remaining, normal, offset, distance_m, cos_max)
            if not big_enough(members):
                failures += 1
                continue
            failures = 0
            piece = connected_pieces(x[members], piece_eps_m, min_points, radii=radii[members],
                                     weights=votes[members], min_weight=min_area_m2)
            for p in np.unique(piece[piece >= 0]):
                idx = members[piece == p]
                n_p, o_p, rms = fit_plane(x[idx], votes[idx])
                planes.append(Plane(n_p, o_p, idx, rms))
            # every member leaves the pool, the small pieces too: left in, they would be found as this plane again
            taken[members] = True
            if progress is not None:
                progress.advance()
    return planes


def _ransac_plane(x, normals, votes, pool, rng, distance_m, cos_max) -> tuple[np.ndarray | None, float]:
    """(unit normal [3], offset [m]) of the plane through three of the pool's Gaussians whose inliers (within
    distance_m, normals agreeing to cos_max) hold the most votes, or (None, nan) when no sample makes a plane.
    Gaussians are drawn in proportion to their votes, so the inliers counted among SCORE_SAMPLES of them
    estimate a plane's share of the area, and hypotheses come from the large surfaces."""
    p = votes[pool] / votes[pool].sum()
    sample = pool[rng.choice(len(pool), size=min(SCORE_SAMPLES, max(len(pool), 3)), p=p)]
    xs, ns = x[sample], normals[sample]
    triples = rng.integers(0, len(sample), size=(RANSAC_ITERATIONS, 3))
    a, b, c = xs[triples[:, 0]], xs[triples[:, 1]], xs[triples[:, 2]]
    n = np.cross(b - a, c - a)
    length = np.linalg.norm(n, axis=1)
    ok = length > 1e-9
    n[ok] /= length[ok, None]
    # a plane none of whose three Gaussians faces along it is not a surface of them: not scored
    ok &= (np.abs(np.einsum("hkj,hj->hk", ns[triples], n)) >= cos_max).all(1)
    if not ok.any():
        return None, float("nan")
    n, d = n[ok], np.einsum("hj,hj->h", n[ok], a[ok])
    best, best_score = 0, -1
    for start in range(0, len(n), 250):        # 250 hypotheses x SCORE_SAMPLES at a time: a few MB
        nb, db = n[start:start + 250], d[start:start + 250]
        inlier = (np.abs(nb @ xs.T - db[:, None]) <= distance_m) & (np.abs(nb @ ns.T) >= cos_max)
        score = inlier.sum(1)
        k = int(np.argmax(score))
        if score[k] > best_score:
            best, best_score = start + k, int(score[k])
    return n[best], float(d[best])


def _members(x, normals, pool, normal, offset, distance_m, cos_max) -> np.ndarray:
    """Indices of pool within distance_m of the plane whose normals agree with it to the angle of cos_max."""
    near = np.abs(x[pool] @ normal - offset) <= distance_m
    agree = np.abs(normals[pool] @ normal) >= cos_max
    return pool[near & agree]
