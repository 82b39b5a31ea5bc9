"""Faces of a labelled mesh that rest against another object's surface: hidden, so no wave meets them.

A box standing on the floor has a bottom face in the floor's plane, facing it; a whiteboard on a wall has a
back face in the wall's plane. Both surfaces are there in the mesh, but nothing can reach the space between
them: a ray tracer that meets the two coincident faces takes one of them for the other at random (Sionna RT
on `rfir simulate`'s classroom), and a surfel model that keeps both reflects twice off the same spot (the
floor under the teacher's desk, and again off the desk's bottom as a slab of wood), which the fit
then pays for with the wrong material on the desk.

A face is a contact face when its three vertices and its centroid lie within `tol_m` of faces of another
label whose normal is opposite to its own (cos below -1 + 1e-6) and whose planes are its own: the face
lies on the other surface, facing it. The other surface is kept where it extends beyond (the floor around
the box); two objects that touch face to face with equal faces (two cabinets side by side) lose both.
Only between labels: an unlabelled mesh, or faces of one object (a plate modelled as two back-to-back
faces), are left as they are.
"""
from __future__ import annotations

import numpy as np

ANTIPARALLEL = 1.0 - 1e-6     # |cos| of the angle between the normals of faces that face each other


def contact_faces(vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray | None, tol_m: float = 1e-3) -> np.ndarray:
    """[F] bool: face f rests against a face of another label (module docstring).

    vertices [V, 3] m; faces [F, 3] vertex indices; labels [F] int or None (None: no face is one);
    tol_m: the largest distance [m] of a point from the other surface, along its normal and beyond its edges."""
    out = np.zeros(len(faces), dtype=bool)
    if labels is None or len(faces) == 0:
        return out
    tri = vertices[faces]                                              # [F, 3, 3]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(cross, axis=1)
    ok = norm > 1e-12
    normal = np.zeros_like(cross)
    normal[ok] = cross[ok] / norm[ok, None]
    offset = np.einsum("fi,fi->f", normal, tri[:, 0])
    # candidate supports by plane: a face f on plane (n, d) rests on faces of plane (-n, -d); bins of the unit
    # normal (to 1e-3) and of the offset (to tol_m), neighbouring offset bins searched too
    key_n = np.round(normal * 1e3).astype(np.int64)
    key_d = np.floor(offset / tol_m).astype(np.int64)
    bins: dict = {}
    for g in np.flatnonzero(ok):
        bins.setdefault((*key_n[g], key_d[g]), []).append(g)
    points = np.concatenate([tri, tri.mean(1, keepdims=True)], 1)      # [F, 4, 3]: vertices and centroid
    for f in np.flatnonzero(ok):
        want = (*(-key_n[f]),)
        cand = [g for dd in (-1, 0, 1) for g in bins.get((*want, -key_d[f] + dd), ())
                if labels[g] != labels[f] and normal[g] @ normal[f] < -ANTIPARALLEL]
        if not cand:
            continue
        covered = np.zeros(4, dtype=bool)
        for g in cand:
            covered |= _on_triangle(points[f], tri[g], normal[g], tol_m)
            if covered.all():
                out[f] = True
                break
    return out


def _on_triangle(p: np.ndarray, t: np.ndarray, n: np.ndarray, tol_m: float) -> np.ndarray:
    """[K] bool: points p [K, 3] within tol_m of triangle t [3, 3] (unit normal n [3]): along the normal and
    beyond each edge."""
    near_plane = np.abs((p - t[0]) @ n) <= tol_m
    inside = np.ones(len(p), dtype=bool)
    for k in range(3):
        a, b = t[k], t[(k + 1) % 3]
        inward = np.cross(n, b - a)                  # in the plane, towards the triangle (counter-clockwise about n)
        inward /= max(np.linalg.norm(inward), 1e-300)
        inside &= (p - a) @ inward >= -tol_m
    return near_plane & inside
