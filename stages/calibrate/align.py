"""Metric alignment: a similarity transform from the SfM frame to the scene's world frame.

References come as known camera centres (a `cameras` artifact or a CSV of name,x,y,z), optionally
with known orientations (a `cameras` artifact has them), or as known 3D points (surveyed points or
ArUco marker corners) triangulated in the SfM frame. The fit is a RANSAC over minimal sets of the
closed-form least-squares similarity (Umeyama 1991), refined on the inliers.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rfir_core.errors import InputFileError, StageError


@dataclass
class CentreReferences:
    """Known camera centres (world, m) by image name; rotations (A,3,3) world_from_camera when known."""

    names: list[str]
    centres: np.ndarray
    rotations: np.ndarray | None = None
    intrinsics: np.ndarray | None = None
    source: str = ""


@dataclass
class PointReferences:
    """Known 3D points (world, m) with their pixel observations (OpenCV convention) per image.

    observations[k] lists (image name, u, v) for point k; labels[k] names it in messages.
    """

    labels: list[str]
    xyz: np.ndarray
    observations: list[list[tuple[str, float, float]]]
    source: str = ""


@dataclass
class Alignment:
    """The fitted sim3 (4,4: [[sR, t], [0, 1]]), its residuals (m) per used reference, and notes."""

    sim3: np.ndarray
    residuals_m: np.ndarray
    inliers: np.ndarray
    labels: list[str]
    method: str
    warnings: list[str] = field(default_factory=list)

    @property
    def scale(self) -> float:
        return float(np.cbrt(np.linalg.det(self.sim3[:3, :3])))


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> np.ndarray:
    """Least-squares similarity (4,4) with dst ~ s R src + t (Umeyama 1991)."""
    mu_s, mu_d = src.mean(0), dst.mean(0)
    a, b = src - mu_s, dst - mu_d
    cov = b.T @ a / len(src)
    U, D, Vt = np.linalg.svd(cov)
    E = np.eye(3)
    E[2, 2] = np.sign(np.linalg.det(U @ Vt)) or 1.0
    R = U @ E @ Vt
    var = (a ** 2).sum(1).mean()
    s = float(np.trace(np.diag(D) @ E) / var) if with_scale and var > 0 else 1.0
    out = np.eye(4)
    out[:3, :3] = s * R
    out[:3, 3] = mu_d - s * R @ mu_s
    return out


def apply(sim3: np.ndarray, x: np.ndarray) -> np.ndarray:
    return x @ sim3[:3, :3].T + sim3[:3, 3]


def rotation_mean(rotations: np.ndarray) -> np.ndarray:
    """Chordal L2 mean of rotations (A,3,3)."""
    U, _, Vt = np.linalg.svd(rotations.sum(0))
    return U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt)) or 1.0]) @ Vt


def fit_sim3(src: np.ndarray, dst: np.ndarray, threshold_m: float, seed: int = 0, iterations: int = 500,
             rotation: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Robust sim3 from point pairs: RANSAC on minimal triples, then least squares on the inliers.

    rotation: a known rotation (3,3) from SfM to world (then only scale and translation are fitted).
    Returns (sim3, inlier mask).
    """
    n = len(src)
    if n < 3:
        raise StageError(f"metric alignment needs at least 3 references, got {n}")

    def fit(idx):
        if rotation is None:
            return umeyama(src[idx], dst[idx])
        rs = src[idx] @ rotation.T
        ms, md = rs.mean(0), dst[idx].mean(0)
        den = ((rs - ms) ** 2).sum()
        s = ((dst[idx] - md) * (rs - ms)).sum() / den if den > 0 else 1.0
        out = np.eye(4)
        out[:3, :3] = s * rotation
        out[:3, 3] = md - s * ms
        return out

    best = np.ones(n, bool)
    if n > 3:
        rng = np.random.default_rng(seed)
        best_count, best_err = -1, np.inf
        for _ in range(iterations):
            idx = rng.choice(n, 3, replace=False)
            model = fit(idx)
            if not np.all(np.isfinite(model)) or np.linalg.det(model[:3, :3]) <= 0:
                continue
            err = np.linalg.norm(apply(model, src) - dst, axis=1)
            inl = err < threshold_m
            score = (inl.sum(), -np.sum(np.minimum(err, threshold_m)))
            if score > (best_count, -best_err):
                best_count, best_err, best = score[0], -score[1], inl
        if best.sum() < 3:
            best = np.ones(n, bool)
    model = fit(np.flatnonzero(best))
    for _ in range(3):  # re-select inliers with the refined model
        inl = np.linalg.norm(apply(model, src) - dst, axis=1) < threshold_m
        if inl.sum() < 3 or np.array_equal(inl, best):
            break
        best = inl
        model = fit(np.flatnonzero(best))
    return model, best


def align_to_centres(names: np.ndarray, world_from_camera: np.ndarray, refs: CentreReferences,
                     threshold_m: float, use_rotations: bool, seed: int = 0) -> Alignment:
    """Fit the sim3 that takes SfM camera centres onto the reference centres."""
    index = {str(n): i for i, n in enumerate(names)}
    used = [k for k, name in enumerate(refs.names) if name in index]
    warnings = []
    missing = len(refs.names) - len(used)
    if missing:
        warnings.append(f"{missing} of {len(refs.names)} reference images did not register; aligned with "
                        f"the other {len(used)}")
    if len(used) < 3:
        raise StageError(f"only {len(used)} of {len(refs.names)} reference images registered; metric alignment "
                         "needs 3 (give references for more images, or photos that overlap more)")
    sfm_idx = np.array([index[refs.names[k]] for k in used])
    src = world_from_camera[sfm_idx, :3, 3]
    dst = refs.centres[used]
    rotation = None
    method = "camera centres"
    if use_rotations and refs.rotations is not None:
        rotation = rotation_mean(refs.rotations[used] @ np.transpose(world_from_camera[sfm_idx, :3, :3], (0, 2, 1)))
        method = "camera poses (rotation averaged, centres for scale and translation)"
    sim3, inliers = fit_sim3(src, dst, threshold_m, seed, rotation=rotation)
    if rotation is not None:
        # drop the outlier images' rotations from the average too, then refit scale and translation
        rotation = rotation_mean(refs.rotations[used][inliers]
                                 @ np.transpose(world_from_camera[sfm_idx[inliers], :3, :3], (0, 2, 1)))
        sim3, inliers = fit_sim3(src, dst, threshold_m, seed, rotation=rotation)
    residuals = np.linalg.norm(apply(sim3, src) - dst, axis=1)
    if (~inliers).any():
        warnings.append(f"{int((~inliers).sum())} reference(s) disagree with the reconstruction by more than "
                        f"{threshold_m:g} m and were left out of the fit")
    return Alignment(sim3, residuals, inliers, [refs.names[k] for k in used], method, warnings)


def triangulate(projections: list[np.ndarray], rays: list[np.ndarray]) -> np.ndarray:
    """Linear (DLT) triangulation from cam_from_world (3,4) matrices and normalised image points (2,)."""
    rows = []
    for P, (x, y) in zip(projections, rays):
        rows.append(x * P[2] - P[0])
        rows.append(y * P[2] - P[1])
    _, _, Vt = np.linalg.svd(np.asarray(rows))
    X = Vt[-1]
    return X[:3] / X[3]


def align_to_points(rec_lookup, refs: PointReferences, threshold_m: float, seed: int = 0) -> Alignment:
    """Triangulate each reference point in the SfM frame from its observations, then fit the sim3.

    rec_lookup(name) -> (cam_from_world (3,4), to_normalised(uv (M,2)) -> (M,2)) or None if unregistered.
    """
    src, dst, labels, warnings = [], [], [], []
    skipped = []
    for label, xyz, obs in zip(refs.labels, refs.xyz, refs.observations):
        Ps, rays = [], []
        for name, u, v in obs:
            hit = rec_lookup(name)
            if hit is None:
                continue
            P, to_norm = hit
            Ps.append(P)
            rays.append(np.asarray(to_norm(np.array([[u, v]], float)))[0])
        if len(Ps) < 2:
            skipped.append(label)
            continue
        src.append(triangulate(Ps, rays))
        dst.append(xyz)
        labels.append(label)
    if skipped:
        warnings.append(f"{len(skipped)} reference point(s) are seen in fewer than 2 registered images and were "
                        f"skipped: {', '.join(skipped[:5])}")
    if len(src) < 3:
        raise StageError(f"only {len(src)} reference point(s) could be triangulated (each needs 2 registered "
                         "images that see it); metric alignment needs 3")
    src, dst = np.asarray(src), np.asarray(dst)
    sim3, inliers = fit_sim3(src, dst, threshold_m, seed)
    residuals = np.linalg.norm(apply(sim3, src) - dst, axis=1)
    if (~inliers).any():
        warnings.append(f"{int((~inliers).sum())} reference point(s) disagree by more than {threshold_m:g} m and "
                        "were left out of the fit")
    return Alignment(sim3, residuals, inliers, labels, "known 3D points", warnings)


def select_subset(n: int, count: int) -> np.ndarray:
    """`count` evenly spread indices out of n (all of them when count <= 0 or >= n)."""
    if count <= 0 or count >= n:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, count)).astype(int))


def load_centre_references(path: str | Path, subset: int = 0) -> CentreReferences:
    """Camera centres from a `cameras` artifact (.h5, with rotations and intrinsics) or a CSV
    (name,x,y,z; a header line is optional). `subset` > 0 keeps that many, evenly spread."""
    path = Path(path)
    if not path.exists():
        raise InputFileError("pose reference file not found", path=path)
    if path.suffix.lower() in (".h5", ".hdf5"):
        from rfir_core.artifacts import read_artifact

        art = read_artifact(path, "cameras")
        names = [str(n) for n in art.data["image_names"]]
        poses = np.asarray(art.data["world_from_camera"], float)
        refs = CentreReferences(names, poses[:, :3, 3], poses[:, :3, :3], np.asarray(art.data["intrinsics"], float),
                                str(path))
    else:
        names, xyz = [], []
        with open(path, newline="") as handle:
            for lineno, row in enumerate(csv.reader(handle), start=1):
                row = [c.strip() for c in row]
                if not row or not any(row) or row[0].startswith("#"):
                    continue
                if len(row) < 4:
                    raise InputFileError(f"line {lineno}: expected name,x,y,z", path=path)
                try:
                    values = [float(c) for c in row[1:4]]
                except ValueError:
                    if lineno == 1:
                        continue  # a header
                    raise InputFileError(f"line {lineno}: x, y, z must be numbers (metres)", path=path) from None
                names.append(row[0])
                xyz.append(values)
        if not names:
            raise InputFileError("no references (expected lines of name,x,y,z)", path=path)
        refs = CentreReferences(names, np.asarray(xyz, float), None, None, str(path))
    if len(set(refs.names)) != len(refs.names):
        raise InputFileError("an image is named more than once", path=path)
    keep = select_subset(len(refs.names), subset)
    return CentreReferences([refs.names[k] for k in keep], refs.centres[keep],
                            None if refs.rotations is None else refs.rotations[keep],
                            None if refs.intrinsics is None else refs.intrinsics[keep], refs.source)


def load_point_references(path: str | Path) -> PointReferences:
    """Known 3D points from a CSV with lines `label,x,y,z,image,u,v` (one line per observation;
    u, v in pixels with the centre of the top-left pixel at (0, 0))."""
    path = Path(path)
    if not path.exists():
        raise InputFileError("point reference file not found", path=path)
    points: dict[str, tuple[np.ndarray, list]] = {}
    with open(path, newline="") as handle:
        for lineno, row in enumerate(csv.reader(handle), start=1):
            row = [c.strip() for c in row]
            if not row or not any(row) or row[0].startswith("#"):
                continue
            if len(row) < 7:
                raise InputFileError(f"line {lineno}: expected label,x,y,z,image,u,v", path=path)
            try:
                xyz = np.array([float(c) for c in row[1:4]])
                u, v = float(row[5]), float(row[6])
            except ValueError:
                if lineno == 1:
                    continue
                raise InputFileError(f"line {lineno}: x, y, z, u, v must be numbers", path=path) from None
            entry = points.setdefault(row[0], (xyz, []))
            if not np.allclose(entry[0], xyz):
                raise InputFileError(f"line {lineno}: point {row[0]!r} has two different positions", path=path)
            entry[1].append((row[4], u, v))
    if not points:
        raise InputFileError("no reference points (expected lines of label,x,y,z,image,u,v)", path=path)
    labels = list(points)
    return PointReferences(labels, np.array([points[k][0] for k in labels]), [points[k][1] for k in labels], str(path))
