"""A surface mesh from the Gaussians: TSDF fusion (Open3D) of their rendered depth maps.

Every training view's rendered colour and depth (z along the camera axis, metres; pixels with
coverage below 0.5 left empty) is integrated into a sparse TSDF voxel grid of voxel size
`voxel_m` with truncation `trunc_voxels * voxel_m`; marching cubes gives the mesh, which the
ray-tracing baseline and the Chamfer metric use.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .data import View, z_from_distance
from .evaluate import ViewMaps


def fuse_tsdf(views: list[View], maps: list[ViewMaps], voxel_m: float, trunc_voxels: float = 4.0,
              min_acc: float = 0.5, training_only: bool = True, max_blocks: int = 10000):
    """Fused open3d.geometry.TriangleMesh (world frame, metres, vertex colours).

    Uses Open3D's voxel block grid (blocks of 8^3 voxels allocated where depth lands); the
    legacy ScalableTSDFVolume of Open3D 0.20 returned empty meshes here.
    """
    import open3d as o3d
    import open3d.core as o3c

    cpu = o3c.Device("CPU:0")
    vbg = o3d.t.geometry.VoxelBlockGrid(attr_names=("tsdf", "weight", "color"),
                                        attr_dtypes=(o3c.float32, o3c.float32, o3c.float32),
                                        attr_channels=((1), (1), (3)), voxel_size=float(voxel_m), block_resolution=8,
                                        block_count=int(max_blocks), device=cpu)
    for v, m in zip(views, maps):
        if training_only and v.split != 0:
            continue
        z = z_from_distance(v, m.distance).astype(np.float32)
        z[(m.acc < min_acc) | ~np.isfinite(z)] = 0.0
        if not (z > 0).any():
            continue
        far = float(z.max() * 1.01)
        depth = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(z)))
        color = o3d.t.geometry.Image(o3c.Tensor(np.ascontiguousarray(np.clip(m.color, 0, 1).astype(np.float32))))
        K = o3c.Tensor(v.K, o3c.float64)
        ext = o3c.Tensor(np.linalg.inv(v.world_from_camera), o3c.float64)
        coords = vbg.compute_unique_block_coordinates(depth, K, ext, 1.0, far, trunc_voxel_multiplier=float(trunc_voxels))
        vbg.integrate(coords, depth, color, K, ext, 1.0, far, trunc_voxel_multiplier=float(trunc_voxels))
    mesh = vbg.extract_triangle_mesh().to_legacy()
    mesh.compute_vertex_normals()
    return mesh


def mesh_arrays(mesh) -> tuple[np.ndarray, np.ndarray]:
    """(vertices [V, 3] m, faces [F, 3] int) of an open3d TriangleMesh."""
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.triangles, dtype=np.int64)


def write_mesh(path: Path, mesh) -> Path:
    """Write the mesh as a binary PLY, atomically (temporary name, then rename)."""
    import open3d as o3d

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.stem}.partial.ply")
    try:
        if not o3d.io.write_triangle_mesh(str(tmp), mesh, write_ascii=False):
            raise OSError(f"open3d could not write {tmp}")
        tmp.replace(path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path
