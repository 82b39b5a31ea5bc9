"""Conforming screen meshes for the boundary-element solver (RWG needs shared vertices on shared edges)."""
from __future__ import annotations

import numpy as np

from rfir_stages.po import dihedral_mesh, plate_mesh, trihedral_mesh


def merge_vertices(vertices: np.ndarray, faces: np.ndarray, tol_m: float = 1e-9):
    """Merge vertices closer than tol_m (V,3 m; F,3 int) -> (vertices, faces) with shared edges."""
    key = np.round(np.asarray(vertices, float) / tol_m).astype(np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return np.asarray(vertices, float)[first], inv.ravel()[np.asarray(faces)]


def plate_screen(size_m: float, n: int):
    """Square plate of side size_m in the y-z plane (normal +x), centred on the origin, 2 n^2 triangles.

    Aspects in the x-y plane then sweep from broadside (phi = 0, 180 deg) to grazing (90, 270 deg),
    with V polarisation (+z) along one edge pair."""
    v, f = plate_mesh(size_m, size_m, n)  # z = 0 plane
    return np.stack([v[:, 2], v[:, 1], v[:, 0]], 1), f


def dihedral_screen(a_m: float, b_m: float, n: int):
    """90-degree dihedral, fold along z (length a_m), plates of width b_m in the planes x = 0 and y = 0,
    opening toward +x +y (bisector phi = 45 deg in the x-y plane); merged vertices on the fold."""
    v, f = dihedral_mesh(a_m, b_m, n)  # fold along y, plates x = 0 and z = 0
    return merge_vertices(np.stack([v[:, 0], v[:, 2], v[:, 1]], 1), f)


def wedge_screen(a_m: float, b_m: float, n: int, angle_deg: float):
    """Two plates a_m (along the fold, z) x b_m (width), n x n squares each, the fold on the z axis: one in the
    half plane y = 0, x >= 0, the other turned by angle_deg about z (the wedge's inner angle), bisector at
    phi = angle_deg / 2 in the x-y plane; merged vertices on the fold. An acute wedge (60 degrees) returns a
    triple-bounce flash on its bisector: the ray one plate turns onto the other at normal incidence."""
    v, f = plate_mesh(b_m, a_m, n)                    # x across [-b/2, b/2], y along the fold, z = 0
    s = v[:, 0] + b_m / 2                             # distance from the fold
    t = np.radians(angle_deg)
    v1 = np.stack([s, np.zeros_like(s), v[:, 1]], 1)
    v2 = np.stack([s * np.cos(t), s * np.sin(t), v[:, 1]], 1)
    return merge_vertices(np.concatenate([v1, v2]), np.concatenate([f, f + len(v)]))


# The trihedral's symmetry plane x = y, spanned by (1, 1, 0)/sqrt(2) and the z edge, becomes the x-y plane:
# rows are the images of those two directions and of their normal (1, -1, 0)/sqrt(2) (right-handed).
_TRIHEDRAL_TO_SWEEP = np.array([[1.0, 1.0, 0.0], [0.0, 0.0, np.sqrt(2.0)], [1.0, -1.0, 0.0]]) / np.sqrt(2.0)
TRIHEDRAL_AXIS_PHI_DEG = float(np.degrees(np.arctan(1.0 / np.sqrt(2.0))))   # 35.26: the axis in the sweep plane


def trihedral_screen(a_m: float, n: int):
    """Square trihedral (plates a_m x a_m, n x n squares each) turned so that its symmetry plane is the
    x-y plane: an azimuth sweep then passes through the triple-bounce peak 12 pi a^4 / lambda^2 at
    phi = TRIHEDRAL_AXIS_PHI_DEG, with H in the symmetry plane and V across it; vertices merged on the edges."""
    v, f = trihedral_mesh(a_m, n)
    return merge_vertices(v @ _TRIHEDRAL_TO_SWEEP.T, f)


def box_surface(a_m: float, b_m: float, c_m: float, edge_m: float):
    """Closed box a_m x b_m x c_m along x, y, z, centred on the origin, each face tiled in squares of at most
    edge_m, triangles wound outward, vertices merged on the box's edges (a closed PEC body for the EFIE;
    pick sizes away from the cavity's interior resonances, where the EFIE fails)."""
    dims = np.array([a_m, b_m, c_m], float)
    verts, faces, base = [], [], 0
    for axis in range(3):
        u, w = (axis + 1) % 3, (axis + 2) % 3              # e_u x e_w = e_axis: counter-clockwise seen from outside
        nu, nw = (int(np.ceil(dims[k] / edge_m - 1e-9)) for k in (u, w))
        U, W = np.meshgrid(np.linspace(-dims[u] / 2, dims[u] / 2, nu + 1),
                           np.linspace(-dims[w] / 2, dims[w] / 2, nw + 1), indexing="ij")
        idx = np.arange((nu + 1) * (nw + 1)).reshape(nu + 1, nw + 1)
        q0, q1, q2, q3 = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
        tri = np.concatenate([np.stack([q0, q1, q2], 1), np.stack([q0, q2, q3], 1)])
        for sign in (1.0, -1.0):
            p = np.zeros((U.size, 3))
            p[:, u], p[:, w], p[:, axis] = U.ravel(), W.ravel(), sign * dims[axis] / 2
            verts.append(p)
            faces.append(base + (tri if sign > 0 else tri[:, ::-1]))
            base += len(p)
    return merge_vertices(np.concatenate(verts), np.concatenate(faces))


def _ring_strip(inner: np.ndarray, outer: np.ndarray) -> np.ndarray:
    """Triangles [T, 3] joining two closed rings of vertex indices (each in increasing angle from 0; the
    inner may be a single centre vertex) so that every ring edge belongs to one triangle: walk both rings
    together, advancing the one whose next vertex comes first in angle."""
    if len(inner) == 1:
        return np.stack([np.full(len(outer), inner[0]), outer, np.roll(outer, -1)], 1)
    ni, no = len(inner), len(outer)
    tris, i, o = [], 0, 0
    while i < ni or o < no:
        if o < no and (i == ni or (o + 1) / no <= (i + 1) / ni):
            tris.append([inner[i % ni], outer[o], outer[(o + 1) % no]])
            o += 1
        else:
            tris.append([inner[i], outer[o % no], inner[(i + 1) % ni]])
            i += 1
    return np.array(tris)


def cylinder_surface(radius_m: float, length_m: float, edge_m: float):
    """Closed circular cylinder of radius_m and length_m, axis along x, centred on the origin: the side a
    polygon of an even number of facets (symmetric under y -> -y and z -> -z, so that an azimuth sweep in
    the x-y plane over 0-90 degrees gives all 360) at most edge_m wide in rings at most edge_m apart, the
    two flat end caps in concentric rings; triangles wound outward, vertices shared on the rims (a closed
    PEC body for the EFIE; keep 2.4 GHz below the cavity's first resonance, TE111, as radius 3 cm does)."""
    n_phi = 2 * int(np.ceil(np.pi * radius_m / edge_m - 1e-9))
    n_x = int(np.ceil(length_m / edge_m - 1e-9))
    n_rings = int(np.ceil(radius_m / edge_m - 1e-9))

    def ring(r, x, n):
        t = 2 * np.pi * np.arange(n) / n
        return np.stack([np.full(n, x), r * np.cos(t), r * np.sin(t)], 1)

    verts = [ring(radius_m, x, n_phi) for x in np.linspace(-length_m / 2, length_m / 2, n_x + 1)]
    faces = []
    idx = np.arange((n_x + 1) * n_phi).reshape(n_x + 1, n_phi)
    a, b = idx[:-1], np.roll(idx[:-1], -1, axis=1)            # ring j, vertex k and k + 1
    c, d = np.roll(idx[1:], -1, axis=1), idx[1:]
    faces.append(np.concatenate([np.stack([a.ravel(), b.ravel(), c.ravel()], 1),   # outward: the volume test
                                 np.stack([a.ravel(), c.ravel(), d.ravel()], 1)]))
    base = (n_x + 1) * n_phi
    for sign, rim in ((-1.0, idx[0]), (1.0, idx[-1])):
        rings = [rim]
        for k in range(n_rings - 1, 0, -1):                   # inward from the rim
            n = max(6, 2 * int(round(n_phi * k / n_rings / 2)))
            verts.append(ring(radius_m * k / n_rings, sign * length_m / 2, n))
            rings.append(base + np.arange(n))
            base += n
        verts.append(np.array([[sign * length_m / 2, 0.0, 0.0]]))
        rings.append(np.array([base]))
        base += 1
        cap = np.concatenate([_ring_strip(rings[k + 1], rings[k]) for k in range(len(rings) - 1)])
        faces.append(cap if sign > 0 else cap[:, ::-1])
    return merge_vertices(np.concatenate(verts), np.concatenate(faces))
