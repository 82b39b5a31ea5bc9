"""The visible part of a ground-truth mesh (geom's Chamfer against what the cameras can see)."""
import numpy as np

from rfir_stages.geom.data import View
from rfir_stages.geom.evaluate import sample_surface, visible_points
from rfir_stages.simulate.scenes import box


def _camera_looking_down_x(at_x: float) -> View:
    """A 64 x 48 camera at (at_x, 0, 0) looking along -x (OpenCV axes: z forward, y down)."""
    c2w = np.eye(4)
    c2w[:3, :3] = np.stack([[0, 1, 0], [0, 0, -1], [-1, 0, 0]], 1)       # columns: camera x, y, z in world
    c2w[:3, 3] = [at_x, 0, 0]
    k = np.array([[40.0, 0, 32], [0, 40.0, 24], [0, 0, 1]])
    return View("cam", np.zeros((48, 64, 3), np.float32), k, c2w, 0)


def test_a_camera_sees_the_near_face_of_a_cube_only():
    import open3d as o3d

    v, f = box((-0.5, -0.5, -0.5), (0.5, 0.5, 0.5))
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(v.astype(np.float32))
    mesh.triangle.indices = o3d.core.Tensor(f.astype(np.int32))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh)
    pts = sample_surface(v, f, 6000, np.random.default_rng(0))
    seen = visible_points(scene, pts, [_camera_looking_down_x(4.0)])
    near = pts[:, 0] > 0.5 - 1e-9
    assert seen[near].mean() > 0.95 and not seen[pts[:, 0] < 0.5 - 0.01].any()   # tolerance: 1e-3 of the range
    both = visible_points(scene, pts, [_camera_looking_down_x(4.0), _camera_looking_down_x(-4.0)])
    assert np.array_equal(both, seen)   # a camera behind the cube facing away sees nothing more
