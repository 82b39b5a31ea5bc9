"""Flat Gaussians (surfels) tiled on a triangle mesh: a geometry oracle for rf-fit and tests.

With `rectangles` (`rfir mesh-gaussians --rectangles`), two coplanar triangles that share an edge and
together form a rectangle (a box's face, a wall's panel between openings) are tiled as the rectangle:
n1 x n2 equal cells of at most spacing / 2 a side (the area of a sub-triangle whose longest edge is the
spacing), each one Gaussian with the cell's centre,
the face normal, in-plane axes along the rectangle's sides and the cell's second moments scaled to its
area. Its footprint cell (rfir_stages.model.surfels.footprint_cells) is then the cell itself, so the
cells' union is the rectangle to the edge; the rotated squares of a triangle tiling overshoot a straight
edge by up to a third of a tile and fall short between (docs/physics.md section 8.10). The room model's
patches then end where the faces end; the physical-optics RCS checks (edge waves, the box against full-wave
data) were made on the sub-triangle tiling, which stays the default.

Every other triangle is split into m x m congruent sub-triangles (m = ceil(longest edge / spacing)), and
each sub-triangle becomes one Gaussian:
- mean: the sub-triangle's centroid [m];
- normal: the face normal (winding v0 -> v1 -> v2, right hand);
- in-plane covariance: the sub-triangle's own second moments, scaled so that the Gaussian's
  projected cross-section along the normal, pi sqrt(det Sigma_2D), equals the sub-triangle's
  area. So the areas A_l seen face-on add up to the mesh area (docs/physics.md sections 2 and 8.6);
- thickness: `thickness_ratio` times the smaller in-plane standard deviation.

Sliver facets (a 32-sided cylinder's side: 1 cm wide, 30 cm tall) would tile into thousands of
sub-triangles a fraction of a millimetre wide that carry almost no area and cost every trace. A
surfel whose smaller in-plane standard deviation is below SLIVER_RATIO x spacing is merged with the
other slivers of its cell (one cell per `spacing` cube, label and normal direction) into one surfel
with the cell's second moments, scaled to the cell's summed area: the covered area is kept, the
count falls to about one per cell. Degenerate facets (zero area) are skipped. `report` counts both.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

SLIVER_RATIO = 0.05      # a surfel narrower (smaller in-plane std) than this x spacing is a sliver
NORMAL_BINS = 3          # normal directions are merged when they round alike at this many steps per axis


def _quat_from_matrix(rot: np.ndarray) -> np.ndarray:
    """Rotation matrices [N, 3, 3] (proper) -> unit quaternions [N, 4] (w, x, y, z)."""
    m = rot
    tr = m[:, 0, 0] + m[:, 1, 1] + m[:, 2, 2]
    cands = np.stack([
        np.stack([1 + tr, m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], -1),
        np.stack([m[:, 2, 1] - m[:, 1, 2], 1 + m[:, 0, 0] - m[:, 1, 1] - m[:, 2, 2], m[:, 0, 1] + m[:, 1, 0],
                  m[:, 0, 2] + m[:, 2, 0]], -1),
        np.stack([m[:, 0, 2] - m[:, 2, 0], m[:, 0, 1] + m[:, 1, 0], 1 - m[:, 0, 0] + m[:, 1, 1] - m[:, 2, 2],
                  m[:, 1, 2] + m[:, 2, 1]], -1),
        np.stack([m[:, 1, 0] - m[:, 0, 1], m[:, 0, 2] + m[:, 2, 0], m[:, 1, 2] + m[:, 2, 1],
                  1 - m[:, 0, 0] - m[:, 1, 1] + m[:, 2, 2]], -1),
    ], 1)  # [N, 4 candidates, 4]; candidate i has component i = 4 q_i^2 (largest is the stable one)
    diag = np.stack([1 + tr, 1 + m[:, 0, 0] - m[:, 1, 1] - m[:, 2, 2], 1 - m[:, 0, 0] + m[:, 1, 1] - m[:, 2, 2],
                     1 - m[:, 0, 0] - m[:, 1, 1] + m[:, 2, 2]], -1)
    q = cands[np.arange(len(m)), diag.argmax(1)]
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    return q * np.where(q[:, :1] < 0, -1.0, 1.0)


def _subdivide(tri: np.ndarray, m: int) -> np.ndarray:
    """One triangle [3, 3] -> its m*m congruent sub-triangles [m*m, 3, 3]."""
    a, b, c = tri
    e1, e2 = (b - a) / m, (c - a) / m
    out = []
    for i in range(m):
        for j in range(m - i):
            p = a + i * e1 + j * e2
            out.append((p, p + e1, p + e2))
            if i + j <= m - 2:
                out.append((p + e1, p + e1 + e2, p + e2))
    return np.asarray(out, dtype=np.float64)


def gaussians_from_mesh(vertices: np.ndarray, faces: np.ndarray, spacing_m: float,
                        labels: np.ndarray | None = None, thickness_ratio: float = 0.05,
                        report: dict | None = None, rectangles: bool = False) -> dict[str, np.ndarray]:
    """Scene fields (`gaussians/...`) of surfels tiling the mesh.

    vertices [V, 3] m, faces [F, 3] int (any winding; the normal follows it), spacing_m: the
    largest sub-triangle edge, twice the largest side of a rectangle's cell [m]; labels [F] int per face
    (optional) -> `gaussians/labels`; rectangles: tile the face pairs that form a rectangle as its cells (module
    docstring; off: every face as sub-triangles).
    Returns dict with means [G, 3], log_scales [G, 3] (in-plane, in-plane, normal), rotations
    [G, 4] wxyz, opacities [G] (ones), normals [G, 3], (labels [G]). Degenerate faces are skipped and
    sliver surfels merged (module docstring); `report`, when given, receives the counts: faces,
    degenerate_faces, sliver_faces, sliver_surfels, merged_surfels, sliver_area_m2, area_m2,
    sliver_width_m (the std below which a surfel is a sliver), rectangles (face pairs tiled as rectangles).
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if spacing_m <= 0:
        raise ValueError(f"spacing_m must be positive, got {spacing_m}")
    tris = vertices[faces]  # [F, 3, 3]
    cross = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    area2 = np.linalg.norm(cross, axis=1)
    keep = area2 > 1e-14
    paired, rects = _rectangles(vertices, faces, cross, area2) if rectangles else (np.zeros(len(faces), bool), [])
    tri_faces = np.flatnonzero(keep & ~paired)
    means, covs, normals, labs = [np.zeros((0, 3))], [np.zeros((0, 3, 3))], [np.zeros((0, 3))], [np.zeros(0, np.int64)]
    for f in tri_faces:
        tri = tris[f]
        longest = max(np.linalg.norm(tri[1] - tri[0]), np.linalg.norm(tri[2] - tri[1]), np.linalg.norm(tri[0] - tri[2]))
        m = max(1, int(math.ceil(longest / spacing_m - 1e-9)))
        sub = _subdivide(tri, m)
        centroid = sub.mean(1)  # [S, 3]
        d = sub - centroid[:, None]
        cov = np.einsum("sij,sik->sjk", d, d) / 12.0  # second moments of a uniform triangle
        means.append(centroid)
        covs.append(np.broadcast_to(cov[0], (len(sub), 3, 3)))  # congruent: same covariance
        normals.append(np.broadcast_to(cross[f] / area2[f], (len(sub), 3)))
        if labels is not None:
            labs.append(np.full(len(sub), int(labels[f])))
        covs[-1] = _scaled_to_area(covs[-1], 0.5 * area2[f] / m**2)
    if not len(tri_faces) and not rects:
        raise ValueError("the mesh has no face with a non-zero area")
    # the lists start with an empty entry, so a mesh of rectangles alone goes through the same steps
    face_of = np.concatenate([np.zeros(0, np.int64)] + [np.full(len(c), f) for f, c in zip(tri_faces, means[1:])])
    means = np.concatenate(means)
    normals = np.ascontiguousarray(np.concatenate(normals))
    cov = np.concatenate(covs)
    lab_all = np.concatenate(labs) if labels is not None else np.zeros(len(means), np.int64)
    means, normals, cov, lab_all, stats = _merge_slivers(means, normals, cov, lab_all, face_of, spacing_m)
    # In-plane axes from the covariance, third axis = the normal.
    ev, evec = np.linalg.eigh(cov)  # ascending; the smallest (~0) is along the normal
    e1 = evec[:, :, 2]
    s1, s2 = np.sqrt(np.maximum(ev[:, 2], 0)), np.sqrt(np.maximum(ev[:, 1], 0))
    if rects:
        cells = [_rectangle_cells(corner, side_1, side_2, spacing_m) for corner, side_1, side_2, _ in rects]
        means = np.concatenate([means] + [c[0] for c in cells])
        normals = np.ascontiguousarray(np.concatenate([normals] + [c[1] for c in cells]))
        e1 = np.concatenate([e1] + [c[2] for c in cells])
        s1 = np.concatenate([s1] + [c[3] for c in cells])
        s2 = np.concatenate([s2] + [c[4] for c in cells])
        lab_of = labels if labels is not None else np.zeros(len(faces), np.int64)
        lab_all = np.concatenate([lab_all] + [np.full(len(c[0]), int(lab_of[r[3]])) for c, r in zip(cells, rects)])
    if labels is not None:
        labs = [lab_all]
    if report is not None:
        report.update(stats, faces=int(len(faces)), degenerate_faces=int((~keep).sum()),
                      area_m2=float(0.5 * area2[keep].sum()), rectangles=len(rects))
    e2 = np.cross(normals, e1)  # exactly in-plane, right-handed with (e1, e2, n)
    e1 = np.cross(e2, normals)
    rot = np.stack([e1, e2, normals], axis=-1)
    s3 = thickness_ratio * np.minimum(s1, s2)
    out = {
        "gaussians/means": means,
        "gaussians/log_scales": np.log(np.stack([s1, s2, s3], 1)),
        "gaussians/rotations": _quat_from_matrix(rot),
        "gaussians/opacities": np.ones(len(means)),
        "gaussians/normals": normals,
    }
    if labels is not None:
        out["gaussians/labels"] = np.concatenate(labs).astype(np.int64)
    return out


def _rectangles(vertices: np.ndarray, faces: np.ndarray, cross: np.ndarray, area2: np.ndarray, tol: float = 1e-6):
    """Pairs of faces that form a rectangle: two non-degenerate triangles sharing an edge (the rectangle's
    diagonal), normals equal (same winding), the four corners a parallelogram with a right angle (to tol
    relative to the diagonal). Each face joins at most one pair. Returns (paired [F] bool, [(corner [3],
    side_1 [3], side_2 [3], face)]): the rectangle is corner + a side_1 + b side_2 for a, b in [0, 1]."""
    opposite: dict = {}
    for f, tri in enumerate(faces):
        if area2[f] <= 1e-14:
            continue
        for k in range(3):
            a, b = int(tri[k]), int(tri[(k + 1) % 3])
            opposite.setdefault((min(a, b), max(a, b)), []).append((f, int(tri[(k + 2) % 3])))
    paired = np.zeros(len(faces), dtype=bool)
    rects = []
    for (a, b), sides in opposite.items():
        if len(sides) != 2:
            continue
        (f1, c1), (f2, c2) = sides
        if paired[f1] or paired[f2] or cross[f1] @ cross[f2] < (1 - 1e-9) * area2[f1] * area2[f2]:
            continue
        diag = np.linalg.norm(vertices[b] - vertices[a])
        side_1, side_2 = vertices[a] - vertices[c1], vertices[b] - vertices[c1]
        if (np.linalg.norm(vertices[c1] + vertices[c2] - vertices[a] - vertices[b]) > tol * diag
                or abs(side_1 @ side_2) > tol * diag * diag):
            continue
        if np.cross(side_1, side_2) @ cross[f1] < 0:      # the sides in the faces' winding
            side_1, side_2 = side_2, side_1
        paired[f1] = paired[f2] = True
        rects.append((vertices[c1], side_1, side_2, f1))
    return paired, rects


def _rectangle_cells(corner: np.ndarray, side_1: np.ndarray, side_2: np.ndarray, spacing_m: float):
    """A rectangle's cells (module docstring): (means [n, 3], normals [n, 3], first in-plane axis [n, 3] (along
    side_1), spreads s1 [n] and s2 [n] m along side_1 and side_2, scaled so that pi s1 s2 is the cell's area)."""
    l1, l2 = float(np.linalg.norm(side_1)), float(np.linalg.norm(side_2))
    # 1e-6: a float32 mesh's 0.4 m side at 0.2 m spacing is 4 cells, not 5
    n1, n2 = (max(1, int(math.ceil(2.0 * length / spacing_m - 1e-6))) for length in (l1, l2))
    i, j = np.meshgrid((np.arange(n1) + 0.5) / n1, (np.arange(n2) + 0.5) / n2, indexing="ij")
    means = corner + i.reshape(-1, 1) * side_1 + j.reshape(-1, 1) * side_2
    normal = np.cross(side_1, side_2)
    normal /= np.linalg.norm(normal)
    count = n1 * n2
    # a uniform a x b cell has spreads a / sqrt(12), b / sqrt(12); scaled to pi s1 s2 = a b: a / sqrt(pi)
    return (means, np.broadcast_to(normal, (count, 3)), np.broadcast_to(side_1 / l1, (count, 3)),
            np.full(count, l1 / n1 / math.sqrt(math.pi)), np.full(count, l2 / n2 / math.sqrt(math.pi)))


def _merge_slivers(means, normals, cov, labels, face_of, spacing_m: float):
    """Merge sliver surfels (smaller in-plane std < SLIVER_RATIO x spacing) per cell (spacing cube,
    label, rounded normal): area-weighted mean and second moments (each surfel's own covariance plus
    its offset), projected on the cell's mean normal and scaled to the cell's summed area.
    Inputs [N, ...] as built above (covariances already area-scaled: pi sqrt(det_2D) = area).
    Returns (means, normals, cov, labels, counts) with the slivers replaced."""
    ev = np.linalg.eigvalsh(cov)                           # ascending; [:, 0] ~ 0 along the normal
    area = math.pi * np.sqrt(np.maximum(ev[:, 1] * ev[:, 2], 0))
    sliver = np.sqrt(np.maximum(ev[:, 1], 0)) < SLIVER_RATIO * spacing_m
    stats = {"sliver_faces": int(np.unique(face_of[sliver]).size), "sliver_surfels": int(sliver.sum()),
             "sliver_area_m2": float(area[sliver].sum()), "merged_surfels": 0,
             "sliver_width_m": SLIVER_RATIO * spacing_m}
    if not sliver.any():
        return means, normals, cov, labels, stats
    m, n, c, a, lab = means[sliver], normals[sliver], cov[sliver], area[sliver], labels[sliver]
    n = n * np.where((n @ np.array([0.577, 0.578, 0.579]))[:, None] < 0, -1.0, 1.0)   # sign-free normals
    key = np.concatenate([np.floor(m / spacing_m), np.round(n * NORMAL_BINS), lab[:, None]], 1).astype(np.int64)
    _, group = np.unique(key, axis=0, return_inverse=True)
    group = group.ravel()
    k = int(group.max()) + 1
    w = np.zeros(k)
    np.add.at(w, group, a)
    mu = np.zeros((k, 3))
    np.add.at(mu, group, a[:, None] * m)
    mu /= w[:, None]
    nn = np.zeros((k, 3))
    np.add.at(nn, group, a[:, None] * n)
    nn /= np.linalg.norm(nn, axis=1, keepdims=True)
    d = m - mu[group]
    second = np.zeros((k, 3, 3))
    np.add.at(second, group, a[:, None, None] * (c + d[:, :, None] * d[:, None, :]))
    proj = np.eye(3)[None] - nn[:, :, None] * nn[:, None, :]
    second = proj @ (second / w[:, None, None]) @ proj
    e = np.linalg.eigvalsh(second)
    det2 = np.maximum(e[:, 1] * e[:, 2], 1e-300)
    # a cell of one collinear strip has no width in its moments: give it the strip's own area as a disc
    flat = e[:, 1] < 1e-12 * np.maximum(e[:, 2], 1e-300)
    second[flat] = proj[flat] * (w[flat] / math.pi)[:, None, None]
    det2[flat] = (w[flat] / math.pi) ** 2
    second = np.where(flat[:, None, None], second, second * (w / (math.pi * np.sqrt(det2)))[:, None, None])
    glab = np.zeros(k, np.int64)
    glab[group] = lab
    stats["merged_surfels"] = k
    keep = ~sliver
    return (np.concatenate([means[keep], mu]), np.ascontiguousarray(np.concatenate([normals[keep], nn])),
            np.concatenate([cov[keep], second]), np.concatenate([labels[keep], glab]), stats)


def _scaled_to_area(cov: np.ndarray, area_m2: float) -> np.ndarray:
    """Scale covariances [S, 3, 3] (rank 2, in-plane) so that pi sqrt(det_2D) = area_m2."""
    ev = np.linalg.eigvalsh(cov[0])
    det2 = ev[1] * ev[2]
    return cov * (area_m2 / (math.pi * math.sqrt(det2)))


def scene_triangles(scene_name: str):
    """A simulate scene's objects (`rfir_stages.simulate.build_scene`) as one mesh: (vertices [V, 3] m,
    faces [F, 3], labels [F], label_names)."""
    from rfir_stages.simulate import build_scene

    spec = build_scene(scene_name)
    verts, faces, labels, off = [], [], [], 0
    for obj in spec.objects:
        verts.append(obj.vertices)
        faces.append(np.asarray(obj.faces) + off)
        labels.append(np.full(len(obj.faces), obj.label))
        off += len(obj.vertices)
    return np.concatenate(verts), np.concatenate(faces), np.concatenate(labels), spec.label_names()


def scene_from_mesh(scene_name: str, spacing_m: float, thickness_ratio: float = 0.05):
    """Surfels of a simulate scene (`rfir_stages.simulate.build_scene`): (fields, label_names)."""
    verts, faces, labels, names = scene_triangles(scene_name)
    fields = gaussians_from_mesh(verts, faces, spacing_m, labels=labels, thickness_ratio=thickness_ratio)
    return fields, names


def write_scene_artifact(path: str | Path, fields: dict, *, label_names=None, source: str = "mesh",
                         spacing_m: float | None = None, rectangles: bool = False,
                         contact_faces_left_out: bool = False) -> Path:
    """Write surfel fields as a `scene` artifact (records the mesh source, spacing, tiling and whether the faces
    resting against another object's surface were left out (geom.contact_faces) in provenance)."""
    from rfir_core.artifacts import write_artifact
    from rfir_core.provenance import Provenance

    attrs = {"source": source}
    if label_names is not None:
        attrs["label_names"] = np.asarray([str(n) for n in label_names], dtype=object)
    prov = Provenance(stage="geom.from_mesh", extra={"source": source, "spacing_m": spacing_m,
                                                         "tiling": "rectangles" if rectangles else "triangles",
                                                         "contact_faces": "left out" if contact_faces_left_out
                                                         else "kept"})
    return write_artifact(path, "scene", fields, attrs=attrs, provenance=prov)
