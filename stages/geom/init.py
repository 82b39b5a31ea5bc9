"""Initial Gaussians from the sparse SfM points of a `calib` artifact.

Each kept point becomes one flat Gaussian: its local plane from a PCA of its k nearest points
(the normal is the direction of least spread), in-plane standard deviation the mean distance to
its 3 nearest points, thickness `thickness_ratio` of that, colour the point's colour. Normals are
oriented away from the points' centroid when the cameras surround the points (an object), and
towards the nearest camera otherwise (a room); training then refines them.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from rfir_core.errors import StageError

from .from_mesh import _quat_from_matrix
from .model import logit


@dataclass
class InitResult:
    """Raw parameters (see model.PARAM_NAMES), the scene extent [m] and how many points were used."""

    params: dict[str, torch.Tensor]
    extent_m: float
    centre: np.ndarray
    num_points: int
    num_dropped: int


def scene_extent(points: np.ndarray) -> tuple[float, np.ndarray]:
    """Diagonal [m] and centre [3] of the 2-98 percentile box of the points (robust to stray points)."""
    lo, hi = np.percentile(points, 2, axis=0), np.percentile(points, 98, axis=0)
    return float(np.linalg.norm(hi - lo)), 0.5 * (lo + hi)


def init_from_points(points: np.ndarray, colors_u8: np.ndarray, cam_centres: np.ndarray, *, max_points: int,
                     init_opacity: float, thickness_ratio: float, knn: int = 8, seed: int = 0,
                     where: str = "calib") -> InitResult:
    """Gaussians from points [P, 3] m with colours [P, 3] uint8; cam_centres [V, 3] m."""
    from scipy.spatial import cKDTree

    points = np.asarray(points, dtype=np.float64)
    colors = np.asarray(colors_u8, dtype=np.float64) / 255.0
    finite = np.all(np.isfinite(points), axis=1)
    points, colors = points[finite], colors[finite]
    if len(points) < 4:
        raise StageError(f"{where}: only {len(points)} sparse points; need at least 4 to start the Gaussians")
    k = min(knn, len(points) - 1)
    tree = cKDTree(points)
    dist, _ = tree.query(points, k=k + 1)
    mean_d = dist[:, 1:].mean(1)
    med = np.median(mean_d)
    mad = np.median(np.abs(mean_d - med)) + 1e-12
    keep = mean_d <= med + 6.0 * 1.4826 * mad  # isolated points are SfM outliers
    dropped = int((~keep).sum())
    points, colors = points[keep], colors[keep]
    rng = np.random.default_rng(seed)
    if max_points > 0 and len(points) > max_points:
        pick = np.sort(rng.choice(len(points), max_points, replace=False))
        points, colors = points[pick], colors[pick]
    n = len(points)
    k = min(knn, n - 1)
    tree = cKDTree(points)
    dist, idx = tree.query(points, k=k + 1)
    nb = points[idx]  # [n, k+1, 3]
    d = nb - nb.mean(1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", d, d) / (k + 1)
    _, evec = np.linalg.eigh(cov)  # ascending eigenvalues
    normal = evec[:, :, 0]
    e1 = evec[:, :, 2]
    extent, centre = scene_extent(points)
    normal = _orient(points, normal, cam_centres, centre)
    e2 = np.cross(normal, e1)
    e1 = np.cross(e2, normal)
    rot = np.stack([e1, e2, normal], axis=-1)
    spacing = np.clip(dist[:, 1:min(4, k + 1)].mean(1), 1e-4 * extent, 0.05 * extent)
    log_s = np.log(np.stack([spacing, spacing, spacing * thickness_ratio], 1))
    params = {
        "means": torch.as_tensor(points, dtype=torch.float32),
        "log_scales": torch.as_tensor(log_s, dtype=torch.float32),
        "rotations": torch.as_tensor(_quat_from_matrix(rot), dtype=torch.float32),
        "opacity_logits": torch.full((n,), float(logit(init_opacity))),
        "color_logits": logit(torch.as_tensor(colors, dtype=torch.float32).clamp(0.02, 0.98)),
        "normals_raw": torch.as_tensor(normal, dtype=torch.float32),
    }
    return InitResult(params, extent, centre, n, dropped)


def _orient(points: np.ndarray, normal: np.ndarray, cams: np.ndarray, centre: np.ndarray) -> np.ndarray:
    lo, hi = points.min(0), points.max(0)
    cam_mean = cams.mean(0)
    inside = bool(np.all(cam_mean > lo) and np.all(cam_mean < hi))
    if inside:  # a room: face the nearest camera
        from scipy.spatial import cKDTree

        _, j = cKDTree(cams).query(points)
        ref = cams[j] - points
    else:  # an object seen from outside: face outwards
        ref = points - centre
    sign = np.where(np.einsum("ni,ni->n", normal, ref) < 0, -1.0, 1.0)
    return normal * sign[:, None]
