"""A reduced calibration data set (rendered once per pytest run) and one SfM run shared by the tests.

14 views of a small textured object (three boxes, ~0.3 m) on two rings spanning 150 degrees, at
640 x 480: the smallest set that registers reliably. Rendering takes ~20 s and SfM ~10 s on 2 cores.
"""
from pathlib import Path

import numpy as np
import pytest

from rfir_stages.render import intrinsics, object_poses, render_views
from rfir_stages.render.toy_scenes import aruco_marker, textured_object_scene

WIDTH, HEIGHT = 640, 480
# ArUco markers (DICT_4X4_50) lying on z = 0 around the object: id, black square side, centre, yaw
MARKERS = [(3, 0.05, (0.21, 0.0, 0.0), 0.0), (7, 0.05, (0.12, 0.165, 0.0), 90.0), (9, 0.05, (-0.08, 0.16, 0.0), 0.0)]


@pytest.fixture(scope="session")
def object_views(tmp_path_factory) -> Path:
    """Folder with images/, cameras.h5 (ground truth) and markers.csv (the marker layout)."""
    root = tmp_path_factory.mktemp("object_views")
    spec = textured_object_scene()
    verts = np.concatenate([o.vertices for o in spec.objects])
    centre = 0.5 * (verts.min(0) + verts.max(0))
    radius = float(np.linalg.norm(verts - centre, axis=1).max())
    K = intrinsics(WIDTH, HEIGHT, 60.0)
    poses = object_poses(centre, radius, 14, K, WIDTH, HEIGHT, np.random.default_rng(0),
                         elevations_deg=[20.0, 45.0], azimuth_span_deg=150.0)
    spec.objects += [aruco_marker(i, size, pos, yaw) for i, size, pos, yaw in MARKERS]
    with open(root / "markers.csv", "w") as handle:
        handle.write("id,size_m,x,y,z,yaw_deg\n")
        for i, size, pos, yaw in MARKERS:
            handle.write(f"{i},{size},{pos[0]},{pos[1]},{pos[2] + 5e-4},{yaw}\n")
    render_views(spec, root, width=WIDTH, height=HEIGHT, poses=poses, spp=16, write_depth=False)
    return root


@pytest.fixture(scope="session")
def sfm_run(object_views, tmp_path_factory):
    """One full calibrate run (SfM with known intrinsics, aligned to the ground-truth centres)."""
    from rfir_stages.calibrate import CalibrateInputs, run

    out = tmp_path_factory.mktemp("sfm_run") / "calib.h5"
    result = run(CalibrateInputs(object_views / "images", out, poses=object_views / "cameras.h5",
                                 intrinsics_from=object_views / "cameras.h5"))
    return result
