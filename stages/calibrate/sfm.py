"""Structure from motion with pycolmap's Python API (the only module that imports pycolmap).

Features, matching, incremental mapping with bundle adjustment, undistortion to pinhole, and
reading an existing COLMAP model. Everything runs in a temporary work folder.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rfir_core.errors import ConfigError, InputFileError, StageError

from .images import ImageSet


@dataclass
class SfmOptions:
    """Structure-from-motion settings (section [calibrate.sfm] of configs/calibrate.toml).

    matcher: "auto" (exhaustive up to exhaustive_max_images; then exhaustive with at most
      reduced_num_features features per photo up to reduced_exhaustive_max_images; above that spatial
      when every photo's centre is known, else sequential), "exhaustive", "sequential" (each photo against the next
      `sequential_overlap`, plus quadratic jumps) or "spatial" (each photo against its
      `spatial_neighbors` nearest known centres; needs a centre for every photo);
    max_num_features: SIFT features per image; max_image_size: longer side used for features (px);
    camera_model: COLMAP model when intrinsics are unknown ("SIMPLE_RADIAL", "PINHOLE", "OPENCV"...);
    max_ignored_distortion_px: distortion smaller than this at the image corners is dropped (no
      resampled copies of the photos are written); min_model_size: smallest model kept;
    num_threads: -1 for all cores; seed: RANSAC / mapper seed (for repeatable runs).
    """

    matcher: str = "auto"
    exhaustive_max_images: int = 60
    reduced_exhaustive_max_images: int = 300
    reduced_num_features: int = 4096
    sequential_overlap: int = 15
    spatial_neighbors: int = 30
    max_num_features: int = 8192
    max_image_size: int = 3200
    camera_model: str = "SIMPLE_RADIAL"
    max_ignored_distortion_px: float = 0.1
    min_model_size: int = 3
    num_threads: int = -1
    seed: int = 0

    def check(self) -> None:
        """Refuse settings that would only fail after minutes of work."""
        if self.matcher not in ("auto", "exhaustive", "sequential", "spatial"):
            raise ConfigError(f"calibrate.sfm.matcher = {self.matcher!r}: expected auto, exhaustive, sequential "
                              "or spatial")
        known = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV",
                 "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE", "OPENCV_FISHEYE", "THIN_PRISM_FISHEYE")
        if self.camera_model not in known:
            raise ConfigError(f"calibrate.sfm.camera_model = {self.camera_model!r}: expected one of {', '.join(known)}")
        if min(self.max_num_features, self.reduced_num_features) < 100 or self.sequential_overlap < 1 or self.spatial_neighbors < 1:
            raise ConfigError("calibrate.sfm: max_num_features must be >= 100, sequential_overlap and "
                              "spatial_neighbors >= 1")


def _pycolmap():
    try:
        import pycolmap
    except ImportError as exc:  # pragma: no cover - the vision extra is missing
        raise StageError(f"pycolmap is not installed ({exc}); install rfir[vision]") from None
    # stages never print: keep COLMAP's own log to errors only
    pycolmap.logging.minloglevel = 2
    pycolmap.logging.stderrthreshold = 2
    return pycolmap


def choose_matcher(options: SfmOptions, n_images: int, all_centres_known: bool) -> tuple[str, int]:
    """(matcher, SIFT features per photo) that `options` resolve to for n_images photos.

    Exhaustive matching costs n^2/2 pairs times features^2: above exhaustive_max_images photos
    "auto" halves the features (a quarter of the cost per pair), above reduced_exhaustive_max_images
    it matches only neighbours (spatial from the known centres, else sequential).
    """
    if options.matcher != "auto":
        return options.matcher, options.max_num_features
    if n_images <= options.exhaustive_max_images:
        return "exhaustive", options.max_num_features
    if n_images <= options.reduced_exhaustive_max_images:
        return "exhaustive", min(options.max_num_features, options.reduced_num_features)
    return ("spatial" if all_centres_known else "sequential"), options.max_num_features


def _write_position_priors(db_path: Path, centres: dict) -> None:
    pycolmap = _pycolmap()
    db = pycolmap.Database.open(str(db_path))
    try:
        for image in db.read_all_images():
            prior = pycolmap.PosePrior()
            prior.corr_data_id = image.data_id
            prior.position = np.asarray(centres[image.name], float)
            prior.coordinate_system = pycolmap.PosePriorCoordinateSystem.CARTESIAN
            db.write_pose_prior(prior)
    finally:
        db.close()


def run_sfm(images: ImageSet, work_dir: Path, options: SfmOptions, progress, known_K: np.ndarray | None = None,
            known_centres: dict | None = None):
    """Run SfM on `images` in `work_dir`; return (largest pycolmap.Reconstruction or None, number of models).

    known_K (3,3, OpenCV pixel convention): fixed pinhole intrinsics shared by all photos.
    known_centres: image name -> world centre (m), used only to pick pairs for spatial matching.
    """
    pycolmap = _pycolmap()
    if hasattr(pycolmap, "set_random_seed"):
        pycolmap.set_random_seed(options.seed)
    db = work_dir / "database.db"
    reader = pycolmap.ImageReaderOptions()
    if known_K is not None:
        reader.camera_model = "PINHOLE"
        # COLMAP's pixel centres sit at +0.5 relative to OpenCV's
        reader.camera_params = ",".join(f"{v:.10g}" for v in (known_K[0, 0], known_K[1, 1],
                                                              known_K[0, 2] + 0.5, known_K[1, 2] + 0.5))
    else:
        reader.camera_model = options.camera_model
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = options.num_threads
    extraction.max_image_size = options.max_image_size
    all_known = known_centres is not None and all(nm in known_centres for nm in images.names)
    matcher, n_features = choose_matcher(options, len(images.names), all_known)
    if matcher == "spatial" and not all_known:
        raise ConfigError("calibrate.sfm.matcher = 'spatial' needs a known centre (--poses) for every photo")
    extraction.sift.max_num_features = n_features
    extraction.use_gpu = False
    chunk = 8
    with progress.task("features", total=len(images.names)) as task:
        for start in range(0, len(images.names), chunk):
            names = images.names[start:start + chunk]
            pycolmap.extract_features(db, images.folder, image_names=names, camera_mode=pycolmap.CameraMode.SINGLE,
                                      reader_options=reader, extraction_options=extraction,
                                      device=pycolmap.Device.cpu)
            task.advance(len(names))
            reader.existing_camera_id = 1  # the later chunks share the first chunk's camera
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = options.num_threads
    matching.use_gpu = False
    with progress.task(f"matching ({matcher})", total=1) as task:
        if matcher == "exhaustive":
            pycolmap.match_exhaustive(db, matching_options=matching, device=pycolmap.Device.cpu)
        elif matcher == "sequential":
            pairing = pycolmap.SequentialPairingOptions()
            pairing.overlap = options.sequential_overlap
            pairing.quadratic_overlap = True
            pairing.loop_detection = False  # needs a vocabulary tree download
            pycolmap.match_sequential(db, matching_options=matching, pairing_options=pairing,
                                      device=pycolmap.Device.cpu)
        elif matcher == "spatial":
            _write_position_priors(db, known_centres)
            pairing = pycolmap.SpatialPairingOptions()
            pairing.max_num_neighbors = options.spatial_neighbors
            pairing.ignore_z = False
            pairing.max_distance = 1e9
            pairing.num_threads = options.num_threads
            pycolmap.match_spatial(db, matching_options=matching, pairing_options=pairing,
                                   device=pycolmap.Device.cpu)
        else:
            raise StageError(f"unknown matcher {options.matcher!r} (expected auto, exhaustive or sequential)")
        task.advance(1)
    mapping = pycolmap.IncrementalPipelineOptions()
    mapping.num_threads = options.num_threads
    mapping.random_seed = options.seed
    mapping.min_model_size = options.min_model_size
    mapping.ba_use_gpu = False
    if known_K is not None:
        mapping.ba_refine_focal_length = False
        mapping.ba_refine_principal_point = False
        mapping.ba_refine_extra_params = False
    out = work_dir / "sparse"
    out.mkdir(parents=True, exist_ok=True)
    with progress.task("mapping", total=len(images.names)) as task:
        models = pycolmap.incremental_mapping(db, images.folder, out, options=mapping,
                                              next_image_callback=lambda: task.advance(1))
    if not models:
        return None, 0
    best = max(models.values(), key=lambda r: r.num_reg_images())
    return best, len(models)


def read_colmap_model(folder: str | Path):
    """Read an existing COLMAP sparse model (cameras/images/points3D as .bin or .txt)."""
    pycolmap = _pycolmap()
    folder = Path(folder)
    if not folder.is_dir():
        raise InputFileError("COLMAP model folder not found", path=folder)
    candidates = [folder] + sorted(p for p in folder.iterdir() if p.is_dir())
    for cand in candidates:
        if any((cand / f"cameras.{ext}").exists() for ext in ("bin", "txt")):
            try:
                return pycolmap.Reconstruction(str(cand))
            except Exception as exc:  # noqa: BLE001 - pycolmap raises plain RuntimeError/ValueError
                raise InputFileError(f"cannot read COLMAP model: {exc}", path=cand) from None
    raise InputFileError("no COLMAP model here (expected cameras.bin/.txt, images.*, points3D.*)", path=folder)


def write_colmap_model(rec, folder: Path) -> None:
    """Write a reconstruction as a binary COLMAP model."""
    folder.mkdir(parents=True, exist_ok=True)
    rec.write(str(folder))


def max_distortion_px(rec) -> float:
    """The largest displacement (px) that the cameras' distortion causes at the image corners/edges."""
    worst = 0.0
    for cam in rec.cameras.values():
        if not cam.extra_params_idxs():
            continue
        w, h = cam.width, cam.height
        border = np.array([[0, 0], [w, 0], [0, h], [w, h], [w / 2, 0], [0, h / 2], [w, h / 2], [w / 2, h]], float)
        rays = np.asarray(cam.cam_from_img(border))
        K = np.asarray(cam.calibration_matrix())
        ideal = rays @ K[:2, :2].T + K[:2, 2]
        worst = max(worst, float(np.max(np.linalg.norm(ideal - border, axis=1))))
    return worst


def drop_distortion(rec) -> None:
    """Set the cameras' distortion parameters to zero in place (used when they are negligible)."""
    for cam in rec.cameras.values():
        params = np.asarray(cam.params, np.float64).copy()
        for i in cam.extra_params_idxs():
            params[i] = 0.0
        cam.params = params


def undistort(rec_dir: Path, image_folder: Path, out_dir: Path, names: list[str]):
    """Undistort the photos of a model to pinhole copies in out_dir/images; return the new model."""
    pycolmap = _pycolmap()
    pycolmap.undistort_images(str(out_dir), str(rec_dir), str(image_folder), image_names=names)
    return pycolmap.Reconstruction(str(out_dir / "sparse"))


def camera_from_image(rec, name: str, uv_opencv: np.ndarray) -> np.ndarray | None:
    """Normalised camera coordinates (M,2) of OpenCV-convention pixels in image `name` (distortion removed)."""
    image = rec.find_image_with_name(name)
    if image is None or not image.has_pose:
        return None
    return np.asarray(image.camera.cam_from_img(np.asarray(uv_opencv, float) + 0.5))


def cam_from_world(rec, name: str) -> np.ndarray | None:
    """(3,4) cam_from_world of a registered image, None if it is not registered."""
    image = rec.find_image_with_name(name)
    if image is None or not image.has_pose:
        return None
    return np.asarray(image.cam_from_world().matrix())


def refine_with_centre_priors(rec, sim3: np.ndarray, names: list[str], centres: np.ndarray, sigma_m: float,
                              refine_intrinsics: bool, num_threads: int = -1, loss_scale_px: float = 0.5) -> int:
    """Move `rec` into the world frame (sim3, SfM -> world) and bundle-adjust it with the known centres.

    Each named image whose centre is known gets a position prior (isotropic standard deviation
    sigma_m, metres). With the centres pinned, a small rotation can no longer trade against a
    sideways shift of the camera, which is what limits the rotations of views close to an object.
    refine_intrinsics: refine the focal length and distortion too (not the principal point);
    loss_scale_px: scale of the Cauchy loss on reprojection errors (a few wrong matches survive
    mapping and would otherwise pull the poses).
    Returns the number of priors used; rec is changed in place.
    """
    pycolmap = _pycolmap()
    s = float(np.cbrt(np.linalg.det(sim3[:3, :3])))
    rec.transform(pycolmap.Sim3d(s, pycolmap.Rotation3d(sim3[:3, :3] / s), sim3[:3, 3]))
    priors = []
    for name, centre in zip(names, np.asarray(centres, float)):
        image = rec.find_image_with_name(str(name))
        if image is None or not image.has_pose:
            continue
        prior = pycolmap.PosePrior()
        prior.corr_data_id = image.data_id
        prior.position = centre
        prior.position_covariance = np.eye(3) * sigma_m ** 2
        prior.coordinate_system = pycolmap.PosePriorCoordinateSystem.CARTESIAN
        priors.append(prior)
    if not priors:
        return 0
    options = pycolmap.BundleAdjustmentOptions()
    options.refine_focal_length = refine_intrinsics
    options.refine_extra_params = refine_intrinsics
    options.refine_principal_point = False
    options.print_summary = False
    options.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    options.ceres.loss_function_scale = loss_scale_px
    options.ceres.solver_options.num_threads = num_threads
    config = pycolmap.BundleAdjustmentConfig()
    for image_id in rec.reg_image_ids():
        config.add_image(image_id)
    adjuster = pycolmap.create_pose_prior_bundle_adjuster(options, pycolmap.PosePriorBundleAdjustmentOptions(),
                                                          config, priors, rec)
    adjuster.solve()
    return len(priors)
