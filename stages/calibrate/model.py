"""A plain-numpy view of an SfM reconstruction (the hand-off between pycolmap and the rest).

Conventions: world_from_camera with OpenCV axes (COLMAP's camera axes are the same: x right,
y down, z forward). Intrinsics use OpenCV's pixel convention (the centre of the top-left pixel is
(0, 0)); COLMAP puts that centre at (0.5, 0.5), so principal points shift by 0.5 px on the way in.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

COLMAP_TO_OPENCV_PX = -0.5


@dataclass
class SfmModel:
    """Registered cameras and sparse points in one frame (SfM's arbitrary one, or the world's).

    names (N,): image names; intrinsics (N,3,3) px; world_from_camera (N,4,4); image_size (N,2);
    reproj_error_px (N,): mean reprojection error of each image's observations;
    points_xyz (P,3), points_rgb (P,3) uint8, points_track_length (P,);
    distortion (N, k): the camera model's extra parameters (all zero for a pinhole);
    camera_model: COLMAP model name of the cameras (e.g. "PINHOLE", "SIMPLE_RADIAL").
    """

    names: np.ndarray
    intrinsics: np.ndarray
    world_from_camera: np.ndarray
    image_size: np.ndarray
    reproj_error_px: np.ndarray
    points_xyz: np.ndarray
    points_rgb: np.ndarray
    points_track_length: np.ndarray
    camera_model: str = "PINHOLE"
    distorted: bool = False

    @property
    def centres(self) -> np.ndarray:
        return self.world_from_camera[:, :3, 3]

    def index(self) -> dict[str, int]:
        return {str(n): i for i, n in enumerate(self.names)}

    def without(self, drop: set[str]) -> "SfmModel":
        """The model without the named images (their points stay)."""
        keep = np.array([str(n) not in drop for n in self.names], bool)
        return replace(self, names=self.names[keep], intrinsics=self.intrinsics[keep],
                       world_from_camera=self.world_from_camera[keep], image_size=self.image_size[keep],
                       reproj_error_px=self.reproj_error_px[keep])

    def transformed(self, sim3: np.ndarray) -> "SfmModel":
        """The model moved by a similarity x -> s R x + t (sim3 = [[sR, t], [0, 1]])."""
        scale = float(np.cbrt(np.linalg.det(sim3[:3, :3])))
        rot = sim3[:3, :3] / scale
        poses = self.world_from_camera.copy()
        poses[:, :3, :3] = rot @ poses[:, :3, :3]
        poses[:, :3, 3] = self.centres @ sim3[:3, :3].T + sim3[:3, 3]
        points = self.points_xyz @ sim3[:3, :3].T + sim3[:3, 3]
        return replace(self, world_from_camera=poses, points_xyz=points)


def _reproj_errors(rec, image) -> float:
    """Per-image mean reprojection error computed by projecting each observed point."""
    cam = image.camera
    obs, pts = [], []
    for p2d in image.points2D:
        if p2d.has_point3D():
            obs.append(p2d.xy)
            pts.append(rec.point3D(p2d.point3D_id).xyz)
    if not pts:
        return 0.0
    pts = np.asarray(pts)
    cam_from_world = image.cam_from_world()
    mat = np.asarray(cam_from_world.matrix())
    pc = pts @ mat[:, :3].T + mat[:, 3]
    ok = pc[:, 2] > 1e-9
    if not np.any(ok):
        return 0.0
    proj = np.asarray(cam.img_from_cam(pc[ok]))
    return float(np.mean(np.linalg.norm(proj[:, :2] - np.asarray(obs)[ok], axis=1)))


def from_reconstruction(rec, errors: bool = True) -> SfmModel:
    """Convert a pycolmap.Reconstruction (registered images only, sorted by name).

    errors=False skips the per-image reprojection errors (zeros), for a quick look at the poses.
    """
    images = sorted((rec.image(i) for i in rec.reg_image_ids()), key=lambda im: im.name)
    n = len(images)
    names = np.array([im.name for im in images])
    Ks = np.zeros((n, 3, 3))
    poses = np.zeros((n, 4, 4))
    sizes = np.zeros((n, 2), np.int64)
    errors_px = np.zeros(n)
    distorted = False
    models = set()
    for k, im in enumerate(images):
        cam = im.camera
        models.add(cam.model_name if hasattr(cam, "model_name") else str(cam.model))
        K = np.asarray(cam.calibration_matrix(), np.float64).copy()
        K[0, 2] += COLMAP_TO_OPENCV_PX
        K[1, 2] += COLMAP_TO_OPENCV_PX
        Ks[k] = K
        extra = [cam.params[i] for i in cam.extra_params_idxs()]
        distorted |= any(abs(float(v)) > 0 for v in extra)
        cam_from_world = np.eye(4)
        cam_from_world[:3, :] = np.asarray(im.cam_from_world().matrix())
        poses[k] = np.linalg.inv(cam_from_world)
        poses[k, 3] = (0.0, 0.0, 0.0, 1.0)
        sizes[k] = (cam.width, cam.height)
        errors_px[k] = _reproj_errors(rec, im) if errors else 0.0
    pids = sorted(rec.point3D_ids())
    xyz = np.array([rec.point3D(p).xyz for p in pids], np.float64).reshape(-1, 3)
    rgb = np.array([rec.point3D(p).color for p in pids], np.uint8).reshape(-1, 3)
    track = np.array([rec.point3D(p).track.length() for p in pids], np.int64)
    return SfmModel(names, Ks, poses, sizes, errors_px, xyz, rgb, track,
                    camera_model="/".join(sorted(models)), distorted=distorted)
