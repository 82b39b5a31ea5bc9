"""Photo renderer for the ground-truth simulator: textured views of a SceneSpec with Mitsuba 3.

`render_views(spec, out_dir, ...)` writes `images/view_000.png ...`, optional depth maps
`depth/view_000.npy` (metres along the camera z axis, 0 where nothing was hit) and a `cameras`
artifact `cameras.h5` with the exact intrinsics and world_from_camera poses (OpenCV axes; pixel
centres at integer coordinates).
"""
from .poses import intrinsics, look_at, object_poses, room_poses
from .render import RenderResult, render_views

__all__ = ["RenderResult", "intrinsics", "look_at", "object_poses", "render_views", "room_poses"]
