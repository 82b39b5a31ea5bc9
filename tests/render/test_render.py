"""The photo renderer: exact camera conventions (a marker lands on its projected pixel), the
cameras artifact, depth maps, and camera placement."""
import cv2
import numpy as np
import pytest

from rfir_core.artifacts import read_artifact
from rfir_stages.render import intrinsics, look_at, object_poses, render_views, room_poses
from rfir_stages.render.poses import obstacle_boxes
from rfir_stages.render.textures import make_texture
from rfir_stages.simulate.scenes import build_scene
from rfir_stages.render.toy_scenes import box_mesh, marker_scene, textured_object_scene

MARKER = np.array([0.1, -0.05, 0.03])
W, H = 320, 240


def _poses(n=4, seed=1):
    rng = np.random.default_rng(seed)
    out = []
    for a in rng.uniform(0, 2 * np.pi, n):
        eye = MARKER + rng.uniform(0.35, 0.8) * np.array([np.cos(a), np.sin(a), 0.8])
        out.append(look_at(eye, MARKER + rng.normal(0, 0.1, 3)))  # marker off the image centre
    return np.stack(out)


@pytest.fixture(scope="module")
def marker_renders(tmp_path_factory):
    """The same views with and without the marker (their difference isolates it, shadow excluded)."""
    root = tmp_path_factory.mktemp("marker")
    poses = _poses()
    spec = marker_scene(MARKER)
    with_marker = render_views(spec, root / "with", width=W, height=H, poses=poses, spp=16, texture_px=256)
    spec.objects = spec.objects[:1]
    without = render_views(spec, root / "without", width=W, height=H, poses=poses, spp=16, texture_px=256,
                           write_depth=False)
    return with_marker, without


def test_marker_lands_on_its_projected_pixel(marker_renders):
    with_marker, without = marker_renders
    cams = read_artifact(with_marker.cameras_path, "cameras")
    for i, (a, b) in enumerate(zip(with_marker.image_paths, without.image_paths)):
        diff = cv2.imread(str(a), cv2.IMREAD_GRAYSCALE).astype(float) - cv2.imread(str(b), cv2.IMREAD_GRAYSCALE)
        mask = diff > 40  # the marker is brighter than the dark floor; its shadow is darker
        assert mask.sum() > 5, f"marker not visible in view {i}"
        ys, xs = np.nonzero(mask)
        K = cams.data["intrinsics"][i]
        cam_from_world = np.linalg.inv(cams.data["world_from_camera"][i])
        pc = cam_from_world[:3, :3] @ MARKER + cam_from_world[:3, 3]
        uv = (K @ pc)[:2] / pc[2]
        # a mirrored axis, a flipped y or a half-pixel convention slip would all exceed this
        assert np.hypot(xs.mean() - uv[0], ys.mean() - uv[1]) < 0.35, (i, xs.mean(), ys.mean(), uv)


def test_depth_is_z_along_the_camera_axis(marker_renders):
    with_marker, _ = marker_renders
    cams = read_artifact(with_marker.cameras_path, "cameras")
    for i, path in enumerate(with_marker.depth_paths):
        depth = np.load(path)
        assert depth.shape == (H, W) and depth.dtype == np.float32
        K = cams.data["intrinsics"][i]
        world_from_camera = cams.data["world_from_camera"][i]
        # back-project the centre pixel: it must lie on the top face of the floor box (z = 0)
        v, u = H // 2, W // 2
        z = float(depth[v, u])
        ray = np.linalg.solve(K, [u, v, 1.0])
        point = world_from_camera[:3, :3] @ (z * ray) + world_from_camera[:3, 3]
        if abs(point[0]) < 0.45 and abs(point[1]) < 0.45 and np.linalg.norm(point - MARKER) > 0.03:
            assert abs(point[2]) < 1e-3, point


def test_cameras_artifact_and_images(marker_renders):
    with_marker, _ = marker_renders
    cams = read_artifact(with_marker.cameras_path, "cameras")
    assert cams.attrs["scene"] == "marker"
    assert list(cams.data["image_names"]) == [p.name for p in with_marker.image_paths]
    assert np.all(cams.data["image_size"] == (W, H))
    K = cams.data["intrinsics"][0]
    assert K[0, 2] == pytest.approx((W - 1) / 2) and K[1, 2] == pytest.approx((H - 1) / 2)
    R = cams.data["world_from_camera"][:, :3, :3]
    assert np.allclose(R @ np.transpose(R, (0, 2, 1)), np.eye(3), atol=1e-9)
    assert np.allclose(np.linalg.det(R), 1.0)
    image = cv2.imread(str(with_marker.image_paths[0]))
    assert image.shape == (H, W, 3)


def test_look_at_is_opencv():
    pose = look_at([2.0, 0.0, 1.0], [0.0, 0.0, 1.0])
    assert np.allclose(pose[:3, 2], [-1, 0, 0])  # z forward
    assert np.allclose(pose[:3, 1], [0, 0, -1])  # y down (world z up)
    assert np.allclose(pose[:3, 0], [0, 1, 0])  # x right: looking along -x, right is +y
    assert np.allclose(np.linalg.det(pose[:3, :3]), 1.0)


def test_object_poses_look_at_the_object():
    K = intrinsics(640, 480, 60.0)
    poses = object_poses([0, 0, 0], 0.3, 60, K, 640, 480, np.random.default_rng(0))
    assert poses.shape == (60, 4, 4)
    to_centre = -poses[:, :3, 3] / np.linalg.norm(poses[:, :3, 3], axis=1, keepdims=True)
    assert np.all(np.einsum("ij,ij->i", to_centre, poses[:, :3, 2]) > 0.99)
    assert np.all(poses[:, 2, 3] > 0)  # above the horizon


def test_room_poses_stay_out_of_objects():
    bounds = np.array([[0.0, 0.0, 0.0], [8.0, 6.0, 3.0]])
    desk = np.stack([np.array([3.0, 2.0, 0.0]), np.array([5.0, 4.0, 2.5])])  # tall block in the middle
    boxes = obstacle_boxes([desk, np.array([[0, 0, 0], [8, 6, 0.01]])], bounds)  # the floor is the shell
    assert len(boxes) == 1
    poses = room_poses(bounds, 30, boxes, np.random.default_rng(0))
    centres = poses[:, :3, 3]
    inside = np.all((centres >= desk[0] - 0.3) & (centres <= desk[1] + 0.3), axis=1)
    assert not inside.any()
    assert np.all((centres > bounds[0]) & (centres < bounds[1]))


def test_textured_object_renders_with_detail(tmp_path):
    spec = textured_object_scene()
    K = intrinsics(160, 120, 60.0)
    poses = object_poses([0, 0, 0.12], 0.2, 2, K, 160, 120, np.random.default_rng(0))
    result = render_views(spec, tmp_path, width=160, height=120, poses=poses, spp=4, texture_px=256,
                          write_depth=False)
    gray = cv2.imread(str(result.image_paths[0]), cv2.IMREAD_GRAYSCALE)
    assert gray.std() > 10  # textured object in front of the plain background
    assert len(box_mesh((0, 0, 0), (1, 1, 1))[1]) == 12


def test_glass_pane_is_bright_and_still_has_features():
    """A pane shows the daylight behind it: brighter than a wall of the same tint by more than a wall's own
    texture spread (so photos can tell a window from its wall), yet with enough detail for SIFT to match it."""
    tint = (0.70, 0.82, 0.88)
    pane = make_texture("glass", tint, 512)
    sift = cv2.SIFT_create()
    for visual in ("plaster", "brick", "wood", "metal", "plastic"):
        wall = make_texture(visual, tint, 512)
        assert pane.mean() - wall.mean() > wall.mean(axis=2).std(), visual
    assert len(sift.detect(cv2.cvtColor((pane * 255).astype(np.uint8), cv2.COLOR_RGB2GRAY), None)) > 500


def test_a_pane_shows_its_own_light(tmp_path):
    """A window is seen by the daylight behind it: its pixels are its texture unshaded (brighter than the lit
    walls around it), and only the pixels whose every sample hits it."""
    spec = build_scene("classroom")
    spec.objects = [o for o in spec.objects if o.name in ("wall_windows", "window_01", "floor", "ceiling")]
    pose = look_at(np.array([4.75, 3.0, 1.6]), np.array([4.75, 0.0, 1.6]))[None]
    result = render_views(spec, tmp_path, width=160, height=120, poses=pose, spp=4, texture_px=128, write_depth=False)
    image = cv2.imread(str(result.image_paths[0]))[..., ::-1] / 255.0
    K = intrinsics(160, 120, 60.0)
    # the pane spans x 4.0-5.5 m, z 0.9-2.3 m on the wall 3 m ahead: its middle and the wall beside it
    col = lambda x: int(K[0, 2] - K[0, 0] * (x - 4.75) / 3.0)      # facing -y: image right is world -x
    row = lambda z: int(K[1, 2] - K[1, 1] * (z - 1.6) / 3.0)
    pane = image[row(2.0):row(1.2), col(5.2):col(4.3)]
    wall = image[row(2.0):row(1.2), col(6.4):col(5.7)]
    assert pane.mean() > 0.8 and pane.mean() - wall.mean() > 0.15
    assert pane.std(axis=(0, 1)).max() > 0.01          # its texture is still there
