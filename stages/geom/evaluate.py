"""After training: render every view, orient the normals, score held-out views, compare with a mesh.

Metrics (docs/physics.md section 9):
- PSNR (dB) and SSIM of the held-out photos (at training resolution);
- normal angular error (degrees) of the rendered normal map against the ground-truth mesh's face
  normals, per pixel of the held-out views where both see a surface; also over the "flat" pixels
  only (the true surface at the pixel and its 4 neighbours is one plane), since at training
  resolution a pixel next to an edge mixes two faces even for a perfect reconstruction;
- depth error (m): median |rendered - true| distance along the pixel rays, same pixels;
- Chamfer distance (m) between the fused surface mesh and the ground-truth mesh:
  0.5 (mean_a min_b |a - b| + mean_b min_a |a - b|) over points sampled by area on both; also
  against the visible part of the truth only (points some view sees), since faces no camera sees
  (undersides, faces between stacked parts) cannot come from photos;
- per-Gaussian normal error: angle between each opaque Gaussian's normal and the normal of the
  nearest ground-truth triangle, ignoring the sign (Gaussians are two-sided surfels); and the
  fraction whose normal points to the same side as that triangle's (winding) normal.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .data import View, camera_rays, z_from_distance
from .losses import psnr, ssim
from .model import GaussianModel
from .gaussian_views import make_scene, render_view


@dataclass
class ViewMaps:
    """Rendered maps of one view (numpy): color [H, W, 3], distance [H, W] m (coverage-normalised),
    normal [H, W, 3] (unit, facing the camera, world frame), acc [H, W]."""

    color: np.ndarray
    distance: np.ndarray
    normal: np.ndarray
    acc: np.ndarray


@torch.no_grad()
def render_all(model: GaussianModel, views: list[View], background: np.ndarray, alpha_min: float, device="cpu",
               progress=None) -> list[ViewMaps]:
    """Render every view (train and held out) with the final Gaussians."""
    scene = make_scene(model, alpha_min)
    bg = torch.as_tensor(background, dtype=torch.float32, device=device)
    out = []
    for v in views:
        origin, dirs = camera_rays(v, device)
        r = render_view(scene, model, origin, dirs, bg)
        n = torch.nn.functional.normalize(r.normal, dim=-1)
        out.append(ViewMaps(r.color.clamp(0, 1).cpu().numpy(), r.expected_depth().cpu().numpy(), n.cpu().numpy(),
                            r.acc.cpu().numpy()))
        if progress is not None:
            progress.advance(1)
    return out


def image_metrics(views: list[View], maps: list[ViewMaps]) -> dict[str, float]:
    """Mean PSNR (dB) and SSIM over the held-out views."""
    ps, ss = [], []
    for v, m in zip(views, maps):
        if v.split != 1:
            continue
        img, ref = torch.as_tensor(m.color), torch.as_tensor(v.image)
        ps.append(psnr(img, ref))
        ss.append(float(ssim(img, ref)))
    if not ps:
        return {}
    return {"psnr_db": float(np.mean(ps)), "ssim": float(np.mean(ss)), "num_test_views": len(ps)}


def orient_normals(model: GaussianModel, views: list[View], maps: list[ViewMaps], tol_rel: float = 0.02) -> int:
    """Turn each Gaussian's normal towards the cameras that see it; returns how many were flipped.

    A Gaussian counts as seen by a training view when its centre projects into the image and lies
    within tol_rel of the rendered depth there (a depth test); its normal is flipped when it points
    away from the mean direction towards those cameras. Unseen Gaussians keep their sign.
    """
    with torch.no_grad():
        mu = model.params["means"].detach().cpu().numpy().astype(np.float64)
        n = model.normals().cpu().numpy().astype(np.float64)
        vote = np.zeros(len(mu))
        for v, m in zip(views, maps):
            if v.split != 0:
                continue
            cam = (mu - v.centre) @ v.world_from_camera[:3, :3]
            z = cam[:, 2]
            front = z > 1e-6
            uv = (cam[:, :2] / np.where(front, z, 1.0)[:, None]) * np.diag(v.K)[:2] + v.K[:2, 2]
            u, w = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
            inside = front & (u >= 0) & (u < v.width) & (w >= 0) & (w < v.height)
            dist = np.linalg.norm(mu - v.centre, axis=1)
            seen = np.zeros(len(mu), dtype=bool)
            ui, wi = u[inside], w[inside]
            seen[inside] = (m.acc[wi, ui] > 0.5) & (np.abs(m.distance[wi, ui] - dist[inside]) < tol_rel * dist[inside])
            to_cam = (v.centre - mu) / np.maximum(dist, 1e-12)[:, None]
            vote += seen * np.sign(np.einsum("ni,ni->n", n, to_cam))
        flip = vote < 0
        raw = model.params["normals_raw"]
        raw[torch.as_tensor(flip, device=raw.device)] *= -1
    return int(flip.sum())


def gt_mesh_metrics(gt_mesh_path: Path, views: list[View], maps: list[ViewMaps], fields: dict[str, np.ndarray],
                    fused_vertices: np.ndarray | None, fused_faces: np.ndarray | None, *, num_points: int = 100000,
                    seed: int = 0) -> dict[str, float]:
    """Normal, depth and surface errors against a ground-truth triangle mesh (PLY)."""
    import open3d as o3d

    from .mesh_io import read_ply_mesh

    gt = read_ply_mesh(gt_mesh_path)
    tmesh = o3d.t.geometry.TriangleMesh()
    tmesh.vertex.positions = o3d.core.Tensor(gt.vertices.astype(np.float32))
    tmesh.triangle.indices = o3d.core.Tensor(gt.faces.astype(np.int32))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(tmesh)
    out: dict[str, float] = {}
    errs, flat_errs, derrs = [], [], []
    for v, m in zip(views, maps):
        if v.split != 1:
            continue
        origin, dirs = camera_rays(v)
        d = dirs.numpy().reshape(-1, 3)
        rays = np.concatenate([np.broadcast_to(origin.numpy(), d.shape), d], axis=1).astype(np.float32)
        hit = scene.cast_rays(o3d.core.Tensor(rays))
        t_hit = hit["t_hit"].numpy()
        n_gt = hit["primitive_normals"].numpy().astype(np.float64)
        n_gt *= np.where(np.einsum("ni,ni->n", n_gt, d) > 0, -1.0, 1.0)[:, None]
        ok = np.isfinite(t_hit) & (m.acc.reshape(-1) > 0.5)
        if not ok.any():
            continue
        cos = np.clip(np.einsum("ni,ni->n", m.normal.reshape(-1, 3), n_gt), -1, 1)
        ang = np.degrees(np.arccos(cos))
        errs.append(ang[ok])
        flat_errs.append(ang[ok & _flat_pixels(n_gt.reshape(v.height, v.width, 3), np.isfinite(t_hit)).reshape(-1)])
        derrs.append(np.abs(m.distance.reshape(-1)[ok] - t_hit[ok]))
    if errs:
        e, f = np.concatenate(errs), np.concatenate(flat_errs)
        out.update({"normal_error_deg_mean": float(e.mean()), "normal_error_deg_median": float(np.median(e)),
                    "depth_error_m_median": float(np.median(np.concatenate(derrs)))})
        if len(f):
            out.update({"normal_error_flat_deg_mean": float(f.mean()), "normal_error_flat_deg_median": float(np.median(f)),
                        "flat_pixel_fraction": float(len(f) / len(e))})
    mu = fields["gaussians/means"]
    opaque = fields["gaussians/opacities"] > 0.5
    if opaque.any():
        q = scene.compute_closest_points(o3d.core.Tensor(mu[opaque].astype(np.float32)))
        dist = np.linalg.norm(q["points"].numpy() - mu[opaque], axis=1)
        ng = q["primitive_normals"].numpy().astype(np.float64)
        signed = np.einsum("ni,ni->n", ng, fields["gaussians/normals"][opaque])
        ang = np.degrees(np.arccos(np.clip(np.abs(signed), 0, 1)))
        out.update({"gaussian_to_mesh_m_mean": float(dist.mean()), "gaussian_normal_error_deg_mean": float(ang.mean()),
                    "gaussian_normal_error_deg_median": float(np.median(ang)),
                    "gaussian_normal_same_side_fraction": float(np.mean(signed > 0))})
    if fused_vertices is not None and fused_faces is not None and len(fused_faces):
        rng = np.random.default_rng(seed)
        a = sample_surface(fused_vertices, fused_faces, num_points, rng)
        b = sample_surface(gt.vertices, gt.faces, num_points, rng)
        acc, comp = chamfer_parts(a, b)
        out.update({"chamfer_m": 0.5 * (acc + comp), "mesh_accuracy_m": acc, "mesh_completeness_m": comp})
        seen = visible_points(scene, b, views)
        if seen.sum() > 100:   # the part of the truth a camera sees: what photos can reconstruct
            acc_v, comp_v = chamfer_parts(a, b[seen])
            out.update({"chamfer_visible_m": 0.5 * (acc_v + comp_v), "mesh_completeness_visible_m": comp_v,
                        "gt_visible_fraction": float(seen.mean())})
        lo, hi = gt.vertices.min(0), gt.vertices.max(0)
        out["gt_extent_m"] = float(np.linalg.norm(hi - lo))
    return out


def visible_points(scene, points: np.ndarray, views: list[View], tol_rel: float = 1e-3) -> np.ndarray:
    """[N] bool: points on the mesh of the Open3D RaycastingScene that some view sees (inside its image,
    in front of it, and the first surface along the ray from its centre)."""
    import open3d as o3d

    seen = np.zeros(len(points), bool)
    for v in views:
        todo = np.flatnonzero(~seen)
        if todo.size == 0:
            break
        c2w = np.asarray(v.world_from_camera, np.float64)
        p_cam = (points[todo] - c2w[:3, 3]) @ c2w[:3, :3]            # camera frame (OpenCV: +z forward)
        z = p_cam[:, 2]
        uv = p_cam @ np.asarray(v.K, np.float64).T
        with np.errstate(divide="ignore", invalid="ignore"):
            u, w = uv[:, 0] / z, uv[:, 1] / z
        inside = (z > 1e-6) & (u >= 0) & (u < v.width) & (w >= 0) & (w < v.height)
        idx = todo[inside]
        if idx.size == 0:
            continue
        d = points[idx] - c2w[:3, 3]
        dist = np.linalg.norm(d, axis=1)
        rays = np.concatenate([np.broadcast_to(c2w[:3, 3], d.shape), d / dist[:, None]], axis=1).astype(np.float32)
        t_hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
        seen[idx[t_hit >= dist * (1 - tol_rel) - 1e-4]] = True
    return seen


def _flat_pixels(n_gt: np.ndarray, hit: np.ndarray, cos_min: float = 0.999) -> np.ndarray:
    """[H, W] pixels whose true surface and that of their 4 neighbours is one plane (no edge nearby)."""
    hit = hit.reshape(n_gt.shape[:2])
    flat = np.zeros(hit.shape, dtype=bool)
    c = n_gt[1:-1, 1:-1]
    ok = hit[1:-1, 1:-1].copy()
    for sl in ((slice(0, -2), slice(1, -1)), (slice(2, None), slice(1, -1)), (slice(1, -1), slice(0, -2)),
               (slice(1, -1), slice(2, None))):
        ok &= hit[sl] & (np.einsum("hwi,hwi->hw", n_gt[sl], c) > cos_min)
    flat[1:-1, 1:-1] = ok
    return flat


def sample_surface(vertices: np.ndarray, faces: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """n points [n, 3] drawn uniformly by area on a triangle mesh."""
    tri = np.asarray(vertices, dtype=np.float64)[np.asarray(faces)]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    f = rng.choice(len(tri), n, p=area / area.sum())
    r1, r2 = np.sqrt(rng.random(n)), rng.random(n)
    t = tri[f]
    return (1 - r1)[:, None] * t[:, 0] + (r1 * (1 - r2))[:, None] * t[:, 1] + (r1 * r2)[:, None] * t[:, 2]


def chamfer_parts(a: np.ndarray, b: np.ndarray) -> tuple[float, float]:
    """(mean over a of the distance to the nearest b, mean over b of the distance to the nearest a), m."""
    from scipy.spatial import cKDTree

    return float(cKDTree(b).query(a)[0].mean()), float(cKDTree(a).query(b)[0].mean())


def write_pngs(folder: Path, views: list[View], maps: list[ViewMaps]) -> list[Path]:
    """Held-out renders: <name>_color.png, _depth.png (z depth, turbo colours), _normal.png
    (camera-frame normal, RGB = (x, -y, -z) / 2 + 1/2, so facing the camera is blue), and _photo.png."""
    import cv2
    from matplotlib import colormaps

    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for v, m in zip(views, maps):
        if v.split != 1:
            continue
        stem = Path(v.name).stem
        z = z_from_distance(v, m.distance)
        mask = m.acc > 0.5
        lo, hi = (np.percentile(z[mask], [2, 98]) if mask.any() else (0.0, 1.0))
        zn = np.clip((z - lo) / max(hi - lo, 1e-9), 0, 1)
        depth_rgb = colormaps["turbo"](1 - zn)[..., :3] * mask[..., None]
        ncam = m.normal @ v.world_from_camera[:3, :3]
        nrgb = (np.stack([ncam[..., 0], -ncam[..., 1], -ncam[..., 2]], -1) * 0.5 + 0.5) * mask[..., None]
        for suffix, img in (("color", m.color), ("depth", depth_rgb), ("normal", nrgb), ("photo", v.image)):
            path = folder / f"{stem}_{suffix}.png"
            cv2.imwrite(str(path), cv2.cvtColor((np.clip(img, 0, 1) * 255).round().astype(np.uint8), cv2.COLOR_RGB2BGR))
            written.append(path)
    return written
