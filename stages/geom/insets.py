"""Parts of a room's surfaces of another material (a door, window panes, a board on a wall): rectangles found from
the photo Gaussians' colour and depth, grouped across the room into classes by appearance, for `rfir structure`.

Photos of textured surfaces give Gaussians of every colour, and a photo Gaussian lies a few centimetres off its
surface, so nothing is decided per Gaussian. Each surface (a wall; the floor and a seen ceiling too) is cut into
square cells of `inset_cell_m`; a cell's appearance is the median colour (RGB) and the median offset from the plane
[m] of its Gaussians within `inset_depth_m` of the plane whose normals are within `normal_deg` of the surface's (a
window set into the wall lies behind it, a board stands out by a centimetre or two). The cells' appearance is
smoothed by the median of each cell's 3 x 3 neighbourhood (texture varies within a cell; an inset is wider than
three cells). The surface's dominant appearance is the median over its own cells, and its own texture spread, per
feature, their median absolute deviation from it (scaled to a standard deviation); its own cells are all of them,
unless their brightness is clearly bimodal (`_own_cells`: bright panes over a quarter of a wall), then the larger
mode's. A cell differs when its
colour (root mean square over R, G, B) or its offset lies more than `inset_spread` spreads from the dominant one.
The threshold is in units of each surface's own spread, so a plain wall and a brick wall are judged alike.

Differing cells, less spurs narrower than three cells, in one 4-connected piece make an inset when they fill at
least `inset_fill` of the seen cells of their bounding box (doors, windows and boards are rectangles; furniture's
shadows and texture blotches are not) and it covers at least `inset_min_m2`. The box's edges are then placed to a
Gaussian's precision: along each edge, every Gaussian is scored by which side of the midway point between the
inset's and the surface's appearance it falls on (projected on the direction in which the two differ, in spread
units), and the edge goes where the scores on its two sides agree best with inside and outside. An inset has
edges: across each edge inside the surface, the median appearance of a cell-wide strip inside exceeds that of the
strip outside by at least half the inset's contrast (a smooth drift of the Gaussians, such as a wall bowing out
under the ceiling, differs without edges).

Insets of all surfaces are grouped by appearance: agglomerative clustering (average linkage) of their median
colour and offset, in units of the room's pooled texture spread (the median of the surfaces' spreads), cut at
`inset_spread`: two insets are of one class when they differ by less than an inset must differ from its wall.
Classes are lettered by their total area (inset_a the largest) and each inset is named inset_A_NN, so that
rf-fit's class sharing (the name less its _NN) gives every class a material of its own.
"""
from __future__ import annotations

import string
from dataclasses import dataclass

import numpy as np

from .room_shell import Surface

MIN_CELL_GAUSSIANS = 4            # a median of fewer Gaussians is one Gaussian's colour: such cells count as unseen
MIN_SPREAD = np.array([0.01, 0.01, 0.01, 0.002])  # spread floors (RGB, offset m): below photo noise, a flat synthetic
#                                                 # colour must not make every rounding error an inset
EDGE_SEARCH_CELLS = 1.5           # an edge is searched this many cells either side of where it stands ...
BIMODAL_SEPARATION = 4.0         # an Otsu split of one normal population separates its halves by 2.65 within-class
#                                 # standard deviations: a surface is of two materials only well beyond that
REFINE_ROUNDS = 4                 # ... and searched again from where it moved, at most this many times


@dataclass
class InsetSettings:
    """Thresholds of the inset search (configs/geom.toml [geom.structure]): lengths in metres, areas in m^2,
    inset_spread in units of a surface's own texture spread, inset_fill a share."""
    normal_deg: float = 25.0
    inset_cell_m: float = 0.25
    inset_depth_m: float = 0.15
    inset_spread: float = 2.5
    inset_fill: float = 0.7
    inset_min_m2: float = 0.5


@dataclass
class _Found:
    """One inset before classing: its host surface, rectangle (u0, u1, v0, v1) [m] along the host's u and v from
    its origin, host cells [nu, nv] bool, its Gaussians [M], appearance [4] (RGB, offset m) and the host's
    dominant appearance [4] and spread [4]."""
    host: Surface
    rect: tuple[float, float, float, float]
    cells: np.ndarray
    members: np.ndarray
    appearance: np.ndarray
    dominant: np.ndarray
    spread: np.ndarray


def find_insets(x: np.ndarray, normals: np.ndarray, colors: np.ndarray, surfaces: list[Surface],
                settings: InsetSettings) -> list[Surface]:
    """The insets of `surfaces` (module docstring) from Gaussians x [N, 3] m with unit normals [N, 3] and colors
    [N, 3] RGB in [0, 1]: new surfaces of kind "inset" named inset_A_NN, in their host's plane and grid, their
    cells cut out of the host's occupancy (host.occupied, host.inset_cells updated). Surfaces without Gaussians
    (an inferred ceiling) are skipped."""
    found = []
    for surface in surfaces:
        if surface.occupied.size == 0 or len(surface.members) == 0:
            continue
        found += surface_insets(x, normals, colors, surface, settings)
    if not found:
        return []
    classes = appearance_classes(found, settings.inset_spread)
    out = []
    order = np.argsort([-sum(f.cells.sum() * f.host.cell_m ** 2 for f, c in zip(found, classes) if c == k)
                        for k in range(classes.max() + 1)], kind="stable")
    letter = {int(k): _letters(rank) for rank, k in enumerate(order)}
    counts: dict[str, int] = {}
    for f, k in zip(found, classes):
        name = letter[int(k)]
        counts[name] = counts.get(name, -1) + 1
        host = f.host
        out.append(Surface(f"inset_{name}_{counts[name]:02d}", "inset", host.normal, host.offset, f.members,
                           host.tilt_deg, origin=host.origin, u=host.u, v=host.v, occupied=f.cells,
                           cell_m=host.cell_m))
        host.occupied = host.occupied & ~f.cells
        host.inset_cells = f.cells if host.inset_cells is None else host.inset_cells | f.cells
    return out


def _letters(rank: int) -> str:
    """0 -> a, 25 -> z, 26 -> aa, ..."""
    letters = string.ascii_lowercase
    return letters[rank] if rank < 26 else _letters(rank // 26 - 1) + letters[rank % 26]


def surface_appearance(x: np.ndarray, normals: np.ndarray, colors: np.ndarray, surface: Surface,
                       settings: InsetSettings):
    """The surface's cells of inset_cell_m and their appearance: (index [M] of the Gaussians in its band, their
    (a, b) [M, 2] m along u, v, their features [M, 4] (RGB, offset from the plane [m]), smoothed cell features
    [nu, nv, 4] (nan: unseen), dominant appearance [4], spread [4])."""
    width, height = surface.size_m
    d = x @ surface.normal - surface.offset
    rel = x - surface.origin
    a, b = rel @ surface.u, rel @ surface.v
    # a band as deep in front as behind (cut nearer on one side, it would pull a board's median offset back); the
    # normal test keeps the neighbouring surfaces' Gaussians (a ceiling's, near a wall's top) out of it
    facing = np.abs(normals @ surface.normal) >= np.cos(np.radians(settings.normal_deg))
    band = (np.abs(d) <= settings.inset_depth_m) & facing & (a >= 0) & (a < width) & (b >= 0) & (b < height)
    idx = np.flatnonzero(band)
    feats = np.concatenate([colors[idx], d[idx, None]], 1)
    cell = settings.inset_cell_m
    nu, nv = max(1, int(np.ceil(width / cell))), max(1, int(np.ceil(height / cell)))
    flat = np.minimum((a[idx] // cell).astype(int), nu - 1) * nv + np.minimum((b[idx] // cell).astype(int), nv - 1)
    order = np.argsort(flat, kind="stable")
    bounds = np.searchsorted(flat[order], np.arange(nu * nv + 1))
    sorted_feats = feats[order]
    cells = np.full((nu * nv, 4), np.nan)
    for k in np.flatnonzero(np.diff(bounds) >= MIN_CELL_GAUSSIANS):
        cells[k] = np.median(sorted_feats[bounds[k]:bounds[k + 1]], axis=0)
    cells = cells.reshape(nu, nv, 4)
    smooth = _median3x3(cells)
    seen = np.isfinite(smooth[..., 0])
    if not seen.any():
        return idx, np.stack([a[idx], b[idx]], 1), feats, smooth, np.full(4, np.nan), np.full(4, np.nan)
    own = smooth[seen][_own_cells(smooth[seen], settings.inset_min_m2 / cell ** 2)]
    dominant = np.median(own, axis=0)
    spread = np.maximum(1.4826 * np.median(np.abs(own - dominant), axis=0), MIN_SPREAD)
    return idx, np.stack([a[idx], b[idx]], 1), feats, smooth, dominant, spread


def _own_cells(cells: np.ndarray, min_cells: float) -> np.ndarray:
    """[M] bool: the cells [M, 4] of the surface's own material. Where the cells' brightness (mean of R, G, B) is
    bimodal - the best two-class split (Otsu's: least within-class variance) separates the class means by more than
    BIMODAL_SEPARATION within-class standard deviations and the smaller class holds at least min_cells cells - the
    larger class alone: bright panes over a quarter of a wall would otherwise pull the median towards them and widen
    the spread until no pane differs by inset_spread. Otherwise all cells."""
    lum = cells[:, :3].mean(axis=1)
    n = len(lum)
    keep = np.ones(n, bool)
    order = np.argsort(lum)
    sorted_lum = lum[order]
    k = np.arange(1, n)                                   # split after the k darkest cells
    allowed = (k >= min_cells) & (n - k >= min_cells)
    if not allowed.any():
        return keep
    csum, csq = np.cumsum(sorted_lum)[:-1], np.cumsum(sorted_lum ** 2)[:-1]
    total, total_sq = sorted_lum.sum(), (sorted_lum ** 2).sum()
    mean_lo, mean_hi = csum / k, (total - csum) / (n - k)
    within = (csq - k * mean_lo ** 2 + (total_sq - csq) - (n - k) * mean_hi ** 2) / n
    best = int(np.argmin(np.where(allowed, within, np.inf)))
    separation = (mean_hi[best] - mean_lo[best]) / np.sqrt(max(within[best], 1e-12))
    if separation <= BIMODAL_SEPARATION:
        return keep
    darker = np.zeros(n, bool)
    darker[order[:best + 1]] = True
    return darker if darker.sum() >= n - darker.sum() else ~darker


def _median3x3(cells: np.ndarray) -> np.ndarray:
    """[nu, nv, F] the median of each seen cell's seen 3 x 3 neighbours (nan where the cell is unseen or fewer than
    5 of its 9 are seen: an edge of the seen area is not judged on two cells)."""
    nu, nv, _ = cells.shape
    pad = np.pad(cells, ((1, 1), (1, 1), (0, 0)), constant_values=np.nan)
    stack = np.stack([pad[i:i + nu, j:j + nv] for i in range(3) for j in range(3)], 0)
    enough = (np.isfinite(stack[..., 0]).sum(0) >= 5) & np.isfinite(cells[..., 0])
    out = np.full(cells.shape, np.nan)
    out[enough] = np.nanmedian(stack[:, enough], axis=0)
    return out


def differing_cells(smooth: np.ndarray, dominant: np.ndarray, spread: np.ndarray, threshold: float) -> np.ndarray:
    """[nu, nv] bool: seen cells whose colour (RMS over RGB) or offset lies more than threshold spreads from the
    dominant appearance."""
    z = (smooth - dominant) / spread
    with np.errstate(invalid="ignore"):
        colour = np.sqrt(np.mean(z[..., :3] ** 2, axis=-1))
        return np.isfinite(colour) & ((colour > threshold) | (np.abs(z[..., 3]) > threshold))


def surface_insets(x: np.ndarray, normals: np.ndarray, colors: np.ndarray, surface: Surface,
                   settings: InsetSettings) -> list[_Found]:
    """The rectangles of one surface that differ from its dominant appearance (module docstring), unclassed."""
    from scipy import ndimage

    idx, ab, feats, smooth, dominant, spread = surface_appearance(x, normals, colors, surface, settings)
    if not np.isfinite(dominant).all():
        return []
    seen = np.isfinite(smooth[..., 0])
    # an opening by 3 x 3 cells cuts the spurs a texture blob beside an inset adds to it (and blobs narrower than
    # three cells, none of them an inset)
    differing = ndimage.binary_opening(differing_cells(smooth, dominant, spread, settings.inset_spread),
                                       np.ones((3, 3), bool))
    pieces, count = ndimage.label(differing)
    cell = settings.inset_cell_m
    out = []
    taken = np.zeros(surface.occupied.shape, bool)
    for p, box in enumerate(ndimage.find_objects(pieces), start=1):
        piece = pieces[box] == p
        if piece.sum() < settings.inset_fill * seen[box].sum() or piece.sum() * cell ** 2 < settings.inset_min_m2:
            continue
        inside_cells = np.zeros(seen.shape, bool)
        inside_cells[box] = piece
        rect = (box[0].start * cell, box[0].stop * cell, box[1].start * cell, box[1].stop * cell)
        i = np.minimum((ab[:, 0] // cell).astype(int), seen.shape[0] - 1)
        j = np.minimum((ab[:, 1] // cell).astype(int), seen.shape[1] - 1)
        appearance = np.median(feats[inside_cells[i, j]], axis=0)
        z = (feats - dominant) / spread
        z_inset = (appearance - dominant) / spread
        for _ in range(REFINE_ROUNDS):     # an edge the cells left short moves on while the Gaussians beyond look inset
            moved = _refined(ab, z, z_inset, rect, cell)
            done = np.abs(np.subtract(moved, rect)).max() < 0.01
            rect = moved
            if done:
                break
        if not _sharp_edges(ab, z, z_inset, rect, cell, surface.size_m):
            continue
        cells = _host_cells(surface, rect, ab, idx) & ~taken
        if cells.sum() * surface.cell_m ** 2 < settings.inset_min_m2:
            continue
        taken |= cells
        hi = np.floor(ab / surface.cell_m).astype(int)
        ok = (hi[:, 0] >= 0) & (hi[:, 0] < cells.shape[0]) & (hi[:, 1] >= 0) & (hi[:, 1] < cells.shape[1])
        members = idx[ok][cells[hi[ok, 0], hi[ok, 1]]]
        out.append(_Found(surface, rect, cells, members, np.median(feats[ok][cells[hi[ok, 0], hi[ok, 1]]], axis=0),
                          dominant, spread))
    return out


def _refined(ab: np.ndarray, z: np.ndarray, z_inset: np.ndarray, rect, cell: float) -> tuple[float, float, float, float]:
    """The rectangle (u0, u1, v0, v1) [m] with each edge moved, within EDGE_SEARCH_CELLS cells, to where the
    Gaussians (positions ab [M, 2], appearance z [M, 4] in spread units from the surface's dominant one) agree best
    with inside (nearer z_inset [4], projected on its direction) and outside."""
    norm = np.linalg.norm(z_inset)
    if not norm > 0:
        return rect
    score = np.where(z @ (z_inset / norm) > norm / 2, 1.0, -1.0)         # +1: looks like the inset
    u0, u1, v0, v1 = rect
    reach = EDGE_SEARCH_CELLS * cell
    for axis in (0, 1):
        lo, hi = (u0, u1) if axis == 0 else (v0, v1)
        c_lo, c_hi = (v0, v1) if axis == 0 else (u0, u1)
        # along the edge, away from the corners (the other axis' edges are not placed yet)
        across = ab[:, 1 - axis]
        inner = (across >= c_lo + cell / 2) & (across <= c_hi - cell / 2)
        lo = _edge(ab[inner, axis], score[inner], lo - reach, min(lo + reach, (lo + hi) / 2), inside_above=True)
        hi = _edge(ab[inner, axis], score[inner], max(hi - reach, (lo + hi) / 2), hi + reach, inside_above=False)
        if axis == 0:
            u0, u1 = lo, hi
        else:
            v0, v1 = lo, hi
    return u0, u1, v0, v1


def _sharp_edges(ab: np.ndarray, z: np.ndarray, z_inset: np.ndarray, rect, cell: float, size_m) -> bool:
    """Whether each edge of rect (u0, u1, v0, v1) [m] inside the surface (of size_m) is a step: the median appearance
    of the Gaussians (ab [M, 2] m, z [M, 4] in spread units) in a strip of one cell just inside it exceeds that just
    outside by at least half the inset's contrast |z_inset| (projected on its direction). A smooth drift of the
    Gaussians (a wall bowing out under the ceiling where the photos see it edge-on) makes a region that differs, not
    one with edges."""
    norm = np.linalg.norm(z_inset)
    if not norm > 0:
        return False
    proj = z @ (z_inset / norm)
    u0, u1, v0, v1 = rect
    for axis, lo, hi, c_lo, c_hi in ((0, u0, u1, v0, v1), (1, v0, v1, u0, u1)):
        t, across = ab[:, axis], ab[:, 1 - axis]
        along = (across >= c_lo + cell / 2) & (across <= c_hi - cell / 2)
        for edge, inward in ((lo, 1.0), (hi, -1.0)):
            if not (cell <= edge <= size_m[axis] - cell):      # an edge on the surface's border has no outside
                continue
            inside = along & (inward * (t - edge) >= 0) & (inward * (t - edge) < cell)
            outside = along & (inward * (edge - t) > 0) & (inward * (edge - t) <= cell)
            if inside.sum() < MIN_CELL_GAUSSIANS or outside.sum() < MIN_CELL_GAUSSIANS:
                continue
            if np.median(proj[inside]) - np.median(proj[outside]) < norm / 2:
                return False
    return True


def _edge(t: np.ndarray, score: np.ndarray, t0: float, t1: float, inside_above: bool) -> float:
    """Position in [t0, t1] that best splits the scores [M] of the Gaussians at t [M] into outside (-1) and inside
    (+1), inside above the edge when inside_above, else below; the window's middle when no Gaussian is in it."""
    sel = (t >= t0) & (t <= t1)
    if not sel.any():
        return 0.5 * (t0 + t1)
    order = np.argsort(t[sel])
    ts, s = t[sel][order], score[sel][order]
    sign = 1.0 if inside_above else -1.0
    # agreement with an edge just before Gaussian k: -s of those below it (outside) + s of those from it (inside)
    below = np.concatenate([[0.0], np.cumsum(s)])
    agree = sign * (below[-1] - 2 * below)
    k = int(np.argmax(agree))
    cuts = np.concatenate([[t0], 0.5 * (ts[1:] + ts[:-1]), [t1]])
    return float(cuts[k])


def _host_cells(surface: Surface, rect, ab: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """[nu, nv] bool: the host's cells (of cell_m) whose centre lies in rect and that are surface or hold a
    Gaussian of the band (a recessed window's cells may have been left as an opening)."""
    u0, u1, v0, v1 = rect
    nu, nv = surface.occupied.shape
    cu = (np.arange(nu) + 0.5) * surface.cell_m
    cv = (np.arange(nv) + 0.5) * surface.cell_m
    in_rect = ((cu >= u0) & (cu <= u1))[:, None] & ((cv >= v0) & (cv <= v1))[None, :]
    held = np.zeros((nu, nv), bool)
    hi = np.floor(ab / surface.cell_m).astype(int)
    ok = (hi[:, 0] >= 0) & (hi[:, 0] < nu) & (hi[:, 1] >= 0) & (hi[:, 1] < nv)
    held[hi[ok, 0], hi[ok, 1]] = True
    return in_rect & (surface.occupied | held)


def appearance_classes(found: list[_Found], threshold: float) -> np.ndarray:
    """[K] class of each inset: average-linkage clusters of their appearances (RGB, offset from the host [m]) in
    units of the pooled spread (median over the hosts), cut at threshold."""
    from scipy.cluster.hierarchy import fcluster, linkage

    if len(found) == 1:
        return np.zeros(1, int)
    pooled = np.median(np.stack([f.spread for f in found]), axis=0)
    feats = np.stack([np.concatenate([f.appearance[:3], [f.appearance[3] - f.dominant[3]]]) for f in found]) / pooled
    # the distance as differing_cells measures it: RMS over RGB, offset on its own, the larger of the two
    colour = feats[:, :3] / np.sqrt(3.0)
    dist = np.maximum(np.linalg.norm(colour[:, None] - colour[None], axis=-1),
                      np.abs(feats[:, None, 3] - feats[None, :, 3]))
    iu = np.triu_indices(len(found), 1)
    tree = linkage(dist[iu], method="average")
    return fcluster(tree, t=threshold, criterion="distance") - 1
