"""rfir calibrate on the reduced rendered set: registration, metric accuracy, the artifact, COLMAP
import equivalence, and the other kinds of metric reference (CSV centres, subsets, 3D points)."""
import csv

import numpy as np

from rfir_core.artifacts import read_artifact
from rfir_core.provenance import sha256_file
from rfir_stages.calibrate import CalibrateInputs, CalibrateOptions, run
from rfir_stages.calibrate.align import fit_sim3, umeyama
from rfir_stages.calibrate.evaluate import pose_errors

# The reduced set spans only 150 degrees of azimuth, so the rotation/translation ambiguity of a
# narrow orbit limits plain SfM (ROTATION_TOL_DEG for runs without all centres known); with every
# centre known, the centre-prior refinement meets the issue's 0.2 degrees here too (measured 0.045).
ISSUE_ROTATION_TOL_DEG = 0.2
CENTRE_TOL_M = 0.01
ROTATION_TOL_DEG = 1.0


def _truth(object_views):
    return read_artifact(object_views / "cameras.h5", "cameras")


def test_reduced_set_registers_and_is_metric(sfm_run, object_views):
    calib = read_artifact(sfm_run.out, "calib")
    errors = pose_errors(calib, _truth(object_views))
    assert errors["registered_fraction"] >= 0.98
    assert errors["centre_error_max_m"] < CENTRE_TOL_M, errors
    assert errors["rotation_error_max_deg"] < ISSUE_ROTATION_TOL_DEG, errors
    assert sfm_run.metric and sfm_run.alignment is not None
    assert sfm_run.alignment.residuals_m.max() < CENTRE_TOL_M
    assert 0.0 < sfm_run.mean_reproj_px < 1.0


def test_artifact_contents(sfm_run, object_views):
    calib = read_artifact(sfm_run.out, "calib")
    d = calib.data
    assert bool(calib.attrs["metric"]) is True
    n = len(d["image_paths"])
    assert d["world_from_camera"].shape == (n, 4, 4) and d["intrinsics"].shape == (n, 3, 3)
    truth = _truth(object_views)
    assert np.allclose(d["intrinsics"], truth.data["intrinsics"][0], atol=1e-6)  # known K kept fixed
    assert np.all(d["image_size"] == (640, 480))
    for rel, digest in zip(d["image_paths"], d["image_sha256"]):
        path = sfm_run.out.parent / rel
        assert path.exists() and sha256_file(path) == digest
    assert len(d["points_xyz"]) == len(d["points_rgb"]) == len(d["points_track_length"]) > 100
    assert d["points_track_length"].min() >= 2
    assert len(d["alignment_residuals_m"]) == len(truth.data["image_names"])
    scale = np.cbrt(np.linalg.det(d["alignment_sim3"][:3, :3]))
    assert scale > 0
    # sparse points sit on the object (about 0.3 m across, standing on z = 0)
    med = np.median(d["points_xyz"], axis=0)
    assert np.all(np.abs(med[:2]) < 0.15) and 0.0 < med[2] < 0.3
    assert sfm_run.plot_path.exists() and sfm_run.plot_path.stat().st_size > 10_000
    assert (sfm_run.model_dir / "cameras.bin").exists()
    assert calib.provenance.stage == "calibrate"


def _import(sfm_run, object_views, out_name, options=None, **kw):
    out = sfm_run.out.parent / out_name
    result = run(CalibrateInputs(object_views / "images", out, colmap_model=sfm_run.model_dir, **kw), options)
    return result, read_artifact(out, "calib")


def test_importing_the_colmap_model_gives_the_same_artifact(sfm_run, object_views):
    # the same references and intrinsics as the original run (the centre-prior refinement keeps K fixed)
    _, imported = _import(sfm_run, object_views, "calib_imported.h5", poses=object_views / "cameras.h5",
                          intrinsics_from=object_views / "cameras.h5")
    original = read_artifact(sfm_run.out, "calib")
    assert set(imported.data) == set(original.data)
    for key, value in original.data.items():
        if value.dtype.kind in "fc":
            # the refinement's multithreaded solver sums in varying order: agreement to ~1e-8, not bits
            np.testing.assert_allclose(imported.data[key], value, rtol=1e-6, atol=1e-6, err_msg=key)
        else:
            np.testing.assert_array_equal(imported.data[key], value, err_msg=key)
    assert bool(imported.attrs["metric"]) is True


def test_centre_prior_refinement(sfm_run, object_views):
    """Bundle adjustment with the known centres pinned: rotations at least as good as without it,
    centres on their references, and alignment_sim3 still maps the raw SfM model to the world."""
    truth = _truth(object_views)
    plain_options = CalibrateOptions.from_config({"centre_prior_m": 0.0})
    plain_result, plain = _import(sfm_run, object_views, "calib_plain.h5", plain_options,
                                  poses=object_views / "cameras.h5")
    assert "refinement" not in plain_result.timings_s and "refinement" in sfm_run.timings_s
    refined = read_artifact(sfm_run.out, "calib")
    e_plain, e_refined = pose_errors(plain, truth), pose_errors(refined, truth)
    assert e_refined["rotation_error_max_deg"] <= e_plain["rotation_error_max_deg"] + 1e-6, (e_plain, e_refined)
    assert e_refined["centre_error_max_m"] < 0.003, e_refined
    assert sfm_run.alignment.residuals_m.max() < 0.003
    # the kept model is the raw SfM model; alignment_sim3 takes its cameras close to the refined ones
    rec_centres = np.stack([c for c in _raw_centres(sfm_run.model_dir, refined.data["image_paths"])])
    moved = rec_centres @ refined.data["alignment_sim3"][:3, :3].T + refined.data["alignment_sim3"][:3, 3]
    assert np.abs(moved - refined.data["world_from_camera"][:, :3, 3]).max() < CENTRE_TOL_M


def _raw_centres(model_dir, image_paths):
    import pycolmap

    rec = pycolmap.Reconstruction(str(model_dir))
    for rel in image_paths:
        image = rec.find_image_with_name(str(rel).replace("\\", "/").split("/")[-1])
        yield np.asarray(image.projection_center())


def test_spatial_matching(object_views, tmp_path):
    """Pairs from the known centres (auto's choice above reduced_exhaustive_max_images photos when
    --poses covers every photo) register the reduced set as well as exhaustive matching does."""
    options = CalibrateOptions.from_config({"sfm": {"matcher": "spatial", "spatial_neighbors": 6}})
    out = tmp_path / "calib.h5"
    run(CalibrateInputs(object_views / "images", out, poses=object_views / "cameras.h5",
                        intrinsics_from=object_views / "cameras.h5"), options)
    errors = pose_errors(read_artifact(out, "calib"), _truth(object_views))
    assert errors["registered_fraction"] >= 0.98, errors
    assert errors["centre_error_max_m"] < CENTRE_TOL_M, errors
    assert errors["rotation_error_max_deg"] < ROTATION_TOL_DEG, errors


def test_matcher_choice():
    from rfir_stages.calibrate.sfm import SfmOptions, choose_matcher

    auto = SfmOptions()
    assert choose_matcher(auto, auto.exhaustive_max_images, True) == ("exhaustive", auto.max_num_features)
    assert choose_matcher(auto, auto.exhaustive_max_images + 1, True) == ("exhaustive", auto.reduced_num_features)
    assert choose_matcher(auto, auto.reduced_exhaustive_max_images + 1, True) == ("spatial", auto.max_num_features)
    assert choose_matcher(auto, auto.reduced_exhaustive_max_images + 1, False) == ("sequential",
                                                                                  auto.max_num_features)
    assert choose_matcher(SfmOptions(matcher="exhaustive"), 1000, True) == ("exhaustive", auto.max_num_features)


def test_csv_centres_and_subset(sfm_run, object_views, tmp_path):
    truth = _truth(object_views)
    path = tmp_path / "centres.csv"
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["name", "x", "y", "z"])
        for name, pose in zip(truth.data["image_names"], truth.data["world_from_camera"]):
            writer.writerow([name, *pose[:3, 3]])
    result, calib = _import(sfm_run, object_views, "calib_csv.h5", poses=path, subset=5)
    assert len(calib.data["alignment_residuals_m"]) == 5
    errors = pose_errors(calib, truth)
    assert errors["centre_error_max_m"] < CENTRE_TOL_M, errors
    assert result.alignment.method == "camera centres"


def test_known_3d_points(sfm_run, object_views, tmp_path):
    """Corners of the object's boxes, 'clicked' in three photos each (projected with the truth)."""
    truth = _truth(object_views)
    corners = np.array([[x, y, z] for x in (-0.15, 0.15) for y in (-0.1, 0.1) for z in (0.0, 0.08)]
                       + [[-0.12, -0.08, 0.25], [0.0, 0.05, 0.25], [0.13, 0.08, 0.15]])
    rows = []
    for k, X in enumerate(corners):
        for i in (1, 6, 11):
            K = truth.data["intrinsics"][i]
            cam_from_world = np.linalg.inv(truth.data["world_from_camera"][i])
            pc = cam_from_world[:3, :3] @ X + cam_from_world[:3, 3]
            u, v = (K @ pc)[:2] / pc[2]
            rows.append([f"p{k}", *X, truth.data["image_names"][i], u, v])
    path = tmp_path / "points.csv"
    with open(path, "w", newline="") as handle:
        csv.writer(handle).writerows([["label", "x", "y", "z", "image", "u", "v"]] + rows)
    result, calib = _import(sfm_run, object_views, "calib_points.h5", points=path)
    assert result.alignment.method == "known 3D points"
    assert calib.data["alignment_residuals_m"].max() < 0.005
    errors = pose_errors(calib, truth)
    assert errors["centre_error_max_m"] < CENTRE_TOL_M, errors


def test_aruco_markers(sfm_run, object_views):
    result, calib = _import(sfm_run, object_views, "calib_markers.h5", markers=object_views / "markers.csv")
    assert result.alignment.method == "known 3D points"
    assert len(result.alignment.labels) == 12  # 3 markers x 4 corners
    assert calib.data["alignment_residuals_m"].max() < 0.005
    errors = pose_errors(calib, _truth(object_views))
    assert errors["centre_error_max_m"] < 2 * CENTRE_TOL_M, errors


def test_no_metric_is_explicit(sfm_run, object_views):
    result, calib = _import(sfm_run, object_views, "calib_nometric.h5", no_metric=True)
    assert bool(calib.attrs["metric"]) is False and not result.metric
    assert np.allclose(calib.data["alignment_sim3"], np.eye(4))
    assert "alignment_residuals_m" not in calib.data


def test_unknown_intrinsics(object_views, tmp_path):
    """SfM estimates the camera (SIMPLE_RADIAL), then the photos are undistorted to a pinhole."""
    out = tmp_path / "calib.h5"
    result = run(CalibrateInputs(object_views / "images", out, poses=object_views / "cameras.h5"))
    calib = read_artifact(out, "calib")
    errors = pose_errors(calib, _truth(object_views))
    assert errors["registered_fraction"] >= 0.98
    assert errors["centre_error_max_m"] < 2 * CENTRE_TOL_M, errors
    K = calib.data["intrinsics"][0]
    assert abs(K[0, 0] / _truth(object_views).data["intrinsics"][0][0, 0] - 1) < 0.03
    for rel in calib.data["image_paths"]:
        assert (out.parent / rel).exists()
    assert result.camera_model


def test_sim3_fit_recovers_a_known_transform_with_outliers():
    rng = np.random.default_rng(3)
    src = rng.normal(size=(30, 3))
    angle = 0.7
    R = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    dst = 2.5 * src @ R.T + np.array([1.0, -2.0, 0.5])
    dst[:4] += 3.0  # outliers
    sim3, inliers = fit_sim3(src, dst, threshold_m=0.05)
    assert inliers.sum() == 26 and not inliers[:4].any()
    assert np.allclose(sim3[:3, :3], 2.5 * R, atol=1e-9)
    assert np.allclose(umeyama(src[4:], dst[4:]), sim3, atol=1e-9)
