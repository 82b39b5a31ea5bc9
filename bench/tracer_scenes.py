"""Surface-fitted Gaussian scenes and pinhole cameras for the tracer benchmark.

A room (walls, floor, ceiling) with a few boxes on the floor; each face is tiled with flat
Gaussians (surfels) on a jittered grid, sized to overlap their neighbours, normals facing out of
the surface. The same construction is cheap enough to build 100k Gaussians in well under a second.
"""
from __future__ import annotations

import math

import torch

# (centre, half-size) of axis-aligned boxes; the first is the room (seen from inside).
ROOM = ((0.0, 0.0, 1.5), (4.0, 3.0, 1.5))
BOXES = (
    ((1.2, 0.6, 0.5), (0.5, 0.5, 0.5)),
    ((-1.0, 1.2, 0.35), (0.6, 0.35, 0.35)),
    ((0.3, -1.1, 0.75), (0.3, 0.3, 0.75)),
    ((-2.2, -1.5, 0.4), (0.4, 0.8, 0.4)),
)


def _faces(centre, half, inward: bool):
    """Six faces as (origin corner, edge u, edge v, normal)."""
    c = torch.tensor(centre, dtype=torch.float64)
    h = torch.tensor(half, dtype=torch.float64)
    out = []
    for axis in range(3):
        for sign in (-1.0, 1.0):
            a, b = [i for i in range(3) if i != axis]
            n = torch.zeros(3, dtype=torch.float64)
            n[axis] = sign
            corner = c.clone()
            corner[axis] += sign * h[axis]
            corner[a] -= h[a]
            corner[b] -= h[b]
            u = torch.zeros(3, dtype=torch.float64)
            v = torch.zeros(3, dtype=torch.float64)
            u[a] = 2 * h[a]
            v[b] = 2 * h[b]
            out.append((corner, u, v, -n if inward else n))
    return out


def _rotation_to(normal: torch.Tensor) -> torch.Tensor:
    """Quaternion wxyz rotating +z onto `normal` (unit)."""
    z = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    c = float(torch.dot(z, normal))
    if c < -0.999999:
        return torch.tensor([0.0, 1.0, 0.0, 0.0], dtype=torch.float64)
    axis = torch.linalg.cross(z, normal)
    q = torch.cat([torch.tensor([1.0 + c], dtype=torch.float64), axis])
    return q / q.norm()


def surface_scene(n_target: int, seed: int = 0, dtype=torch.float32):
    """Flat Gaussians tiled on the room and boxes, about n_target of them.

    Returns dict(means [N,3], log_scales [N,3], rotations [N,4], opacities [N], normals [N,3],
    features [N,3] colours) in `dtype`.
    """
    g = torch.Generator().manual_seed(seed)
    faces = _faces(*ROOM, inward=True)
    for c, h in BOXES:
        faces += _faces(c, h, inward=False)
    areas = [float(torch.linalg.cross(u, v).norm()) for _, u, v, _ in faces]
    spacing = math.sqrt(sum(areas) / n_target)
    parts = {k: [] for k in ("means", "log_scales", "rotations", "normals")}
    for (corner, u, v, n), _area in zip(faces, areas):
        nu = max(1, round(float(u.norm()) / spacing))
        nv = max(1, round(float(v.norm()) / spacing))
        iu, iv = torch.meshgrid(torch.arange(nu), torch.arange(nv), indexing="ij")
        su = (iu.reshape(-1) + 0.5 + 0.3 * (torch.rand(nu * nv, generator=g, dtype=torch.float64) - 0.5)) / nu
        sv = (iv.reshape(-1) + 0.5 + 0.3 * (torch.rand(nu * nv, generator=g, dtype=torch.float64) - 0.5)) / nv
        m = corner + su[:, None] * u + sv[:, None] * v
        k = m.shape[0]
        # the local frame of _rotation_to(n) maps x, y to two in-plane axes; tangent sizes
        # follow the grid pitch along each edge, the normal axis is nearly flat
        pitch = torch.tensor([float(u.norm()) / nu, float(v.norm()) / nv], dtype=torch.float64)
        q = _rotation_to(n)
        R = _rotmat(q)
        ex = R[:, 0].abs()
        along_u = float(torch.dot(ex, u.abs() / u.norm())) > 0.5
        sx, sy = (pitch[0], pitch[1]) if along_u else (pitch[1], pitch[0])
        ls = torch.log(torch.tensor([0.8 * sx, 0.8 * sy, 1e-3 * min(sx, sy)], dtype=torch.float64))
        parts["means"].append(m)
        parts["log_scales"].append(ls.expand(k, 3))
        parts["rotations"].append(q.expand(k, 4))
        parts["normals"].append(n.expand(k, 3))
    out = {k: torch.cat(v).to(dtype).contiguous() for k, v in parts.items()}
    n_total = out["means"].shape[0]
    out["opacities"] = (0.85 + 0.14 * torch.rand(n_total, generator=g, dtype=torch.float64)).to(dtype)
    out["features"] = torch.rand(n_total, 3, generator=g, dtype=torch.float64).to(dtype)
    return out


def _rotmat(q: torch.Tensor) -> torch.Tensor:
    w, x, y, z = q.tolist()
    return torch.tensor([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ], dtype=torch.float64)


def pinhole_rays(width: int, height: int, fov_deg: float = 70.0, eye=(3.4, 2.4, 1.9),
                 target=(0.0, 0.0, 0.5), dtype=torch.float32):
    """Unit rays of a pinhole camera (one per pixel centre): (origins [3], directions [H*W, 3])."""
    eye_t = torch.tensor(eye, dtype=torch.float64)
    fwd = torch.tensor(target, dtype=torch.float64) - eye_t
    fwd = fwd / fwd.norm()
    up = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    right = torch.linalg.cross(fwd, up)
    right = right / right.norm()
    down = torch.linalg.cross(fwd, right)
    f = 0.5 * width / math.tan(math.radians(fov_deg) / 2)
    ys, xs = torch.meshgrid(torch.arange(height, dtype=torch.float64) + 0.5,
                            torch.arange(width, dtype=torch.float64) + 0.5, indexing="ij")
    d = (fwd * f + right * (xs[..., None] - width / 2) + down * (ys[..., None] - height / 2)).reshape(-1, 3)
    d = d / d.norm(dim=1, keepdim=True)
    return eye_t.to(dtype), d.to(dtype).contiguous()
