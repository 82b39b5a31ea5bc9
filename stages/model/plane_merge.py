"""Planes of scattered Gaussians: their scatter about local planes, and planar patches grown by plane fit
(docs/physics.md section 8.10).

Joining neighbours whose offsets along the normal differ by less than `coplanar_m` (second_order.planar_patches)
keeps exact surfels' planes exact. Gaussians from photos scatter by a centimetre or two about their surface:
at 1 cm they fall apart into thousands of small patches, and at any tolerance one stray neighbour pair joins
two surfaces (the faces of a slab, a wall and the furniture against it), since joining is transitive. Here
planes are fitted instead: components (every Gaussian its own, to begin with) merge with adjacent ones
(some neighbour pair between them) while the plane fitted to their union holds each of them, with parallel
normals and an RMS offset from that plane of at most `tol_m` (the two faces of a slab, each half their
distance from the joint plane, stay apart). The plane of a set of surfels is the area-weighted mean of their
normals (sign-aligned) through their area-weighted centroid, as a patch's plane is. Every test is against
the union's own plane, so a slow bend cannot chain the way neighbour offsets do.

`tol_m` comes from the Gaussians' own scatter (`offset_scatter_m`, times `SCATTER_FACTOR`): on exact surfels it
is zero and neighbours are joined as before.
"""
from __future__ import annotations

import numpy as np

SCATTER_FACTOR = 2.0     # merge tolerance in units of the scatter: RMS offsets of the Gaussians of one plane are about 1


def offset_scatter_m(x: np.ndarray, i: np.ndarray, j: np.ndarray, parallel: np.ndarray) -> float:
    """Robust scatter [m] of Gaussians about their local planes.

    x [G, 3]: means [m]; i, j [E]: neighbour pairs; parallel [E] bool: the pairs whose normals are parallel and
    point the same way (the far face of a thin slab is not part of a Gaussian's local plane).
    Per Gaussian, the plane fitted (least squares) to it and its parallel neighbours, and the RMS offset of
    those points from it (sqrt of the smallest eigenvalue of their covariance, times sqrt(k / (k - 3)) for k
    points: three degrees of freedom go into the plane); the scene's scatter is the median of those over the
    Gaussians with at least 6 such neighbours. The normals do not enter (their own scatter would count
    twice); on exact surfels it is zero up to rounding, whatever their thin slabs' opposite faces do (a
    minority)."""
    i, j = i[parallel], j[parallel]
    g = len(x)
    if len(i) == 0:
        return 0.0
    owner = np.concatenate([i, j, np.arange(g)])
    other = np.concatenate([j, i, np.arange(g)])
    count = np.bincount(owner, minlength=g).astype(float)
    rel = x[other] - x[owner]                      # about the owner: no cancellation against the room's size
    m1 = np.stack([np.bincount(owner, weights=rel[:, k], minlength=g) for k in range(3)], 1) / count[:, None]
    m2 = np.stack([np.stack([np.bincount(owner, weights=rel[:, k] * rel[:, m], minlength=g) for m in range(3)], 1)
                   for k in range(3)], 1) / count[:, None, None]
    cov = m2 - m1[:, :, None] * m1[:, None, :]
    enough = count >= 7
    if not enough.any():
        return 0.0
    lam = np.linalg.eigvalsh(cov[enough])[:, 0].clip(0.0)
    k = count[enough]
    return float(np.median(np.sqrt(lam * k / (k - 3.0))))


def _plane_stats(comp: np.ndarray, x: np.ndarray, n: np.ndarray, a: np.ndarray, num: int):
    """Area-weighted sums per component [num, ...]: weight w, first and second moments of the positions x (about
    their mean: no cancellation against the room's size) and the sum of the normals, each aligned with its
    component's first surfel (planar_patches' convention)."""
    first = np.full(num, -1)
    first[comp[::-1]] = np.arange(len(comp))[::-1]
    sign = np.where((n * n[first[comp]]).sum(1) < 0, -1.0, 1.0)
    xr = x - x.mean(0)
    w = np.bincount(comp, weights=a, minlength=num)
    m1 = np.stack([np.bincount(comp, weights=a * xr[:, k], minlength=num) for k in range(3)], 1)
    m2 = np.stack([np.stack([np.bincount(comp, weights=a * xr[:, k] * xr[:, m], minlength=num) for m in range(3)], 1)
                   for k in range(3)], 1)
    ns = np.stack([np.bincount(comp, weights=a * sign * n[:, k], minlength=num) for k in range(3)], 1)
    return w, m1, m2, ns


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-300)


def _offsets_ms(w, m1, m2, c, nrm, p):
    """Mean-square offset [E] m^2 of component c's surfels from the planes (unit normals nrm [E, 3] through p [E, 3])."""
    mu = m1[c] / w[c][:, None]
    var = np.einsum("ei,eij,ej->e", nrm, m2[c], nrm) / w[c] - np.einsum("ei,ei->e", nrm, mu) ** 2
    return var.clip(0.0) + np.einsum("ei,ei->e", nrm, mu - p) ** 2


def _pair_costs(stats, a_c: np.ndarray, b_c: np.ndarray, parallel_cos: float) -> np.ndarray:
    """[E] the larger RMS offset [m] of components a_c's and b_c's surfels from the plane of their union (inf where
    their normals are not parallel)."""
    w, m1, m2, ns = stats
    dot = np.einsum("ei,ei->e", _unit(ns[a_c]), _unit(ns[b_c]))
    s = np.where(dot < 0, -1.0, 1.0)[:, None]
    nrm = _unit(ns[a_c] + s * ns[b_c])
    p = (m1[a_c] + m1[b_c]) / (w[a_c] + w[b_c])[:, None]
    worst = np.maximum(_offsets_ms(w, m1, m2, a_c, nrm, p), _offsets_ms(w, m1, m2, b_c, nrm, p))
    return np.where(np.abs(dot) >= parallel_cos, np.sqrt(worst), np.inf)


def _group_members_fit(stats, group: np.ndarray, parallel_cos: float, tol_m: float) -> np.ndarray:
    """[C] bool: component c lies on the plane of its group (the union of the components with its group id) within
    tol_m RMS, its normal parallel to the group's."""
    w, m1, m2, ns = stats
    num = int(group.max()) + 1
    ref = np.full(num, -1)
    ref[group[::-1]] = np.arange(len(group))[::-1]
    sign = np.where(np.einsum("ci,ci->c", ns, ns[ref[group]]) < 0, -1.0, 1.0)
    gw = np.bincount(group, weights=w, minlength=num)
    gm1 = np.stack([np.bincount(group, weights=m1[:, k], minlength=num) for k in range(3)], 1)
    gns = np.stack([np.bincount(group, weights=sign * ns[:, k], minlength=num) for k in range(3)], 1)
    nrm = _unit(gns)[group]
    ms = _offsets_ms(w, m1, m2, np.arange(len(group)), nrm, (gm1 / gw[:, None])[group])
    return (ms <= tol_m * tol_m) & (np.abs(np.einsum("ci,ci->c", _unit(ns), nrm)) >= parallel_cos)


def merge_coplanar(comp: np.ndarray, x: np.ndarray, n: np.ndarray, a: np.ndarray, i: np.ndarray, j: np.ndarray,
                   parallel_cos: float, tol_m: float, max_rounds: int = 200) -> np.ndarray:
    """Component labels [G] after merging adjacent coplanar components (see the module docstring).

    comp [G]: each surfel's component (every surfel its own for Gaussians from photos); x, n [G, 3]; a [G]
    areas m^2; i, j [E]: neighbour pairs allowed to join (one label); parallel_cos: the normals' |cos| at
    least; tol_m: RMS offset at most, m.

    In rounds, all at once: every component points at the adjacent one it merges with most cheaply (the
    smallest larger RMS offset, within tol_m), the trees of these pointers are merged, and a component that
    its tree's plane does not hold (tol_m, parallel normals) is let go again, until every member fits; a
    round that keeps no merge merges the mutual choices alone, which their pair cost holds. The rounds end
    when no adjacent pair can merge."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    _, comp = np.unique(comp, return_inverse=True)
    comp = comp.reshape(-1)
    if tol_m <= 0 or len(i) == 0:
        return comp
    for _ in range(max_rounds):
        num = int(comp.max()) + 1
        ca, cb = comp[i], comp[j]
        cross = ca != cb
        if not cross.any():
            break
        i, j = i[cross], j[cross]                 # pairs inside one component stay inside it: drop them for good
        key = np.sort(np.minimum(ca[cross], cb[cross]) * num + np.maximum(ca[cross], cb[cross]))
        key = key[np.r_[True, key[1:] != key[:-1]]]   # distinct (np.unique's hashing is 100 times slower here)
        edges = np.stack([key // num, key % num], 1)
        stats = _plane_stats(comp, x, n, a, num)
        cost = _pair_costs(stats, edges[:, 0], edges[:, 1], parallel_cos)
        ok = cost <= tol_m
        if not ok.any():
            break
        edges, cost = edges[ok], cost[ok]
        order = np.lexsort((np.arange(len(cost)), cost))          # cheapest first, ties by index: a strict order
        ends = np.concatenate([edges[order, 0], edges[order, 1]])
        rank = np.concatenate([order, order])
        pos = np.concatenate([np.arange(len(order)), np.arange(len(order))])
        by = np.lexsort((pos, ends))
        firsts = by[np.r_[True, ends[by][1:] != ends[by][:-1]]]
        chooser = ends[firsts]
        chosen = edges[rank[firsts]]
        target = np.where(chosen[:, 0] == chooser, chosen[:, 1], chosen[:, 0])
        graph = coo_matrix((np.ones(len(chooser)), (chooser, target)), shape=(num, num))
        group = connected_components(graph, directed=False)[1]
        for _ in range(8):                                          # let go of the members their plane does not hold
            fits = _group_members_fit(stats, group, parallel_cos, tol_m)
            if fits.all():
                break
            group = np.where(fits, group, group.max() + 1 + np.arange(num))
            group = np.unique(group, return_inverse=True)[1].reshape(-1)
        else:
            group = np.arange(num)
        if group.max() + 1 == num:                                   # nothing kept: the mutual choices alone
            mutual = np.zeros(num, dtype=np.int64) - 1
            mutual[chooser] = target
            pair = np.flatnonzero((mutual >= 0) & (mutual[np.clip(mutual, 0, None)] == np.arange(num)))
            group = np.arange(num)
            group[pair] = np.minimum(pair, mutual[pair])
            group = np.unique(group, return_inverse=True)[1].reshape(-1)
        comp = group[comp]
    return comp
