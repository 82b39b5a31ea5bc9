"""The receiver's direction grid (docs/physics.md section 5.1, step 3; paper appendix "Antenna FoV discretization").

Cells of `step_deg` in polar angle theta (from the antenna axis) and azimuth phi: theta covers
0..180 deg (omni, 180 x 360 at 1 deg) or 0..90 deg (front-only antennas such as the horn,
90 x 360). Each ray goes through its cell centre and carries the cell's solid angle
dOmega = (cos theta_0 - cos theta_1) dphi [sr] (exact, so the weights add up to 4 pi or 2 pi).
"""
from __future__ import annotations

import math

import torch


def local_grid(step_deg: float, front_only: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """Unit directions [N, 3] in the antenna frame (axis = +z) and solid angles [N] in sr."""
    if not 0.0 < step_deg <= 30.0:
        raise ValueError(f"grid step must be in (0, 30] degrees, got {step_deg}")
    n_t = int(round((90.0 if front_only else 180.0) / step_deg))
    n_p = int(round(360.0 / step_deg))
    t_edges = torch.linspace(0.0, math.pi / 2 if front_only else math.pi, n_t + 1, dtype=torch.float64)
    theta = 0.5 * (t_edges[1:] + t_edges[:-1])
    phi = (torch.arange(n_p, dtype=torch.float64) + 0.5) * (2 * math.pi / n_p)
    band = (torch.cos(t_edges[:-1]) - torch.cos(t_edges[1:])) * (2 * math.pi / n_p)  # [n_t]
    th, ph = torch.meshgrid(theta, phi, indexing="ij")
    dirs = torch.stack([torch.sin(th) * torch.cos(ph), torch.sin(th) * torch.sin(ph), torch.cos(th)], -1)
    return dirs.reshape(-1, 3), band[:, None].expand(n_t, n_p).reshape(-1).clone()


def frame_from_axis(axis: torch.Tensor) -> torch.Tensor:
    """A rotation [3, 3] whose third column is the unit `axis` [3] (columns: x', y', z' in world)."""
    z = axis / axis.norm()
    helper = torch.tensor([1.0, 0.0, 0.0], dtype=z.dtype) if abs(float(z[0])) < 0.9 else \
        torch.tensor([0.0, 1.0, 0.0], dtype=z.dtype)
    x = torch.linalg.cross(helper, z)
    x = x / x.norm()
    y = torch.linalg.cross(z, x)
    return torch.stack([x, y, z], -1)


def rays_toward_sphere(origin: torch.Tensor, axis: torch.Tensor, centre: torch.Tensor, radius_m: float,
                       local_dirs: torch.Tensor, local_domega: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The grid rays of an antenna at `origin` [3] with `axis` [3] that can meet a sphere.

    Rays outside the cone from the origin around the sphere (centre [3], radius [m]) hit nothing
    there, so leaving them out changes no result. Returns world directions [n, 3] and dOmega [n].
    """
    frame = frame_from_axis(axis)
    to_c = centre - origin
    dist = float(to_c.norm())
    if dist <= radius_m:
        return local_dirs @ frame.T, local_domega
    half = math.asin(min(1.0, radius_m / dist))
    keep = local_dirs @ (frame.T @ (to_c / dist)) >= math.cos(half)   # test in the antenna frame
    return local_dirs[keep] @ frame.T, local_domega[keep]


def frames_from_axes(axes: torch.Tensor) -> torch.Tensor:
    """`frame_from_axis` for many axes [M, 3] at once: rotations [M, 3, 3]."""
    z = axes / axes.norm(dim=-1, keepdim=True)
    use_x = (z[:, :1].abs() < 0.9).to(z.dtype)
    helper = torch.cat([use_x, 1.0 - use_x, torch.zeros_like(use_x)], -1)
    x = torch.linalg.cross(helper, z)
    x = x / x.norm(dim=-1, keepdim=True)
    y = torch.linalg.cross(z, x)
    return torch.stack([x, y, z], -1)


def rays_toward_sphere_batch(origins: torch.Tensor, axes: torch.Tensor, centre: torch.Tensor, radius_m: float,
                             local_dirs: torch.Tensor, local_domega: torch.Tensor, chunk: int = 64
                             ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """`rays_toward_sphere` for M antennas (origins, axes [M, 3]) in one pass.

    Returns world directions [H, 3], dOmega [H] and the antenna index [H] of each ray, grouped by
    antenna in order (the same rays, in the same order, as M calls of `rays_toward_sphere`).
    Antennas go in chunks of `chunk` so the [chunk, N] cone test stays small."""
    parts = [_rays_toward_sphere_chunk(origins[a:a + chunk], axes[a:a + chunk], centre, radius_m, local_dirs,
                                       local_domega) for a in range(0, origins.shape[0], chunk)]
    offsets = range(0, origins.shape[0], chunk)
    if not parts:
        return local_dirs[:0], local_domega[:0], torch.zeros(0, dtype=torch.int64)
    return (torch.cat([p[0] for p in parts]), torch.cat([p[1] for p in parts]),
            torch.cat([p[2] + a for p, a in zip(parts, offsets)]))


def _rays_toward_sphere_chunk(origins, axes, centre, radius_m, local_dirs, local_domega):
    frames = frames_from_axes(axes)                                   # [M, 3, 3]
    to_c = centre[None] - origins
    dist = to_c.norm(dim=-1)
    half = torch.asin((radius_m / dist).clamp(max=1.0))
    local_c = torch.einsum("mji,mj->mi", frames, to_c / dist[:, None])  # frame^T (to_c / dist)
    keep = (local_c @ local_dirs.T) >= torch.cos(half)[:, None]        # [M, N]
    keep |= (dist <= radius_m)[:, None]
    link, cell = keep.nonzero(as_tuple=True)
    dirs = torch.einsum("hij,hj->hi", frames[link], local_dirs[cell])
    return dirs, local_domega[cell], link

