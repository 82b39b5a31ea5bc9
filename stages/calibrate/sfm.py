"""Structure from motion with pycolmap's Python API (the only module that imports pycolmap).

Features, matching, incremental mapping with bundle adjustment, undistortion to pinhole, and
reading an existing COLMAP model. Everything runs in a temporary work folder.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rfir_core.errors import ConfigError, InputFileError, StageError

from . import matcher_choice
from .images import ImageSet


@dataclass
class SfmOptions:
    """Structure-from-motion settings (section [calibrate.sfm] of configs/calibrate.toml).

    matcher: "auto" (exhaustive up to exhaustive_max_images; above that sequential when a probe finds the
      photos to be a sequence (matcher_choice.py), else exhaustive with at most reduced_num_features features
      per photo up to reduced_exhaustive_max_images and above that spatial when every photo's centre is known,
      else sequential), "exhaustive", "sequential" (each photo against the next `sequential_overlap`, plus
      quadratic jumps and keyframes every `loop_closure_period` photos against each other) or "spatial" (each
      photo against its `spatial_neighbors` nearest known centres; needs a centre for every photo);
    probe_pairs, probe_num_features, probe_min_inliers, probe_near_far_ratio: the sequence probe's neighbouring
      and far pairs (each), its SIFT features per photo, the inliers a verified pair has and how many times the
      far pairs' median inliers the neighbours' must reach; sequential_min_registered_fraction: below it, auto's
      sequential matching is redone exhaustively;
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
    loop_closure_period: int = 10
    probe_pairs: int = 8
    probe_num_features: int = 1024
    probe_min_inliers: int = 15
    probe_near_far_ratio: float = 2.0
    sequential_min_registered_fraction: float = 0.9
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
        if min(self.max_num_features, self.reduced_num_features, self.probe_num_features) < 100 \
                or self.sequential_overlap < 1 or self.spatial_neighbors < 1 or self.probe_pairs < 1:
            raise ConfigError("calibrate.sfm: max_num_features, reduced_num_features and probe_num_features must be "
                              ">= 100, sequential_overlap, spatial_neighbors and probe_pairs >= 1")
        if self.loop_closure_period < 0 or not 0 <= self.sequential_min_registered_fraction <= 1:
            raise ConfigError("calibrate.sfm: loop_closure_period must be >= 0 and sequential_min_registered_fraction "
                              "within [0, 1]")


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
    """(matcher, SIFT features per photo) that `options` resolve to for n_images photos without the sequence probe
    (matcher_choice.choose runs the probe and takes this rule when the photos are not a sequence).

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


def _reader_options(options: SfmOptions, known_K: np.ndarray | None):
    pycolmap = _pycolmap()
    reader = pycolmap.ImageReaderOptions()
    if known_K is not None:
        reader.camera_model = "PINHOLE"
        # COLMAP's pixel centres sit at +0.5 relative to OpenCV's
        reader.camera_params = ",".join(f"{v:.10g}" for v in (known_K[0, 0], known_K[1, 1],
                                                              known_K[0, 2] + 0.5, known_K[1, 2] + 0.5))
    else:
        reader.camera_model = options.camera_model
    return reader


def _extract(db: Path, images: ImageSet, names: list[str], options: SfmOptions, known_K, n_features: int,
             task=None) -> None:
    """SIFT features of the photos `names` into the database db, n_features at most per photo, one shared camera."""
    pycolmap = _pycolmap()
    reader = _reader_options(options, known_K)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = options.num_threads
    extraction.max_image_size = options.max_image_size
    extraction.sift.max_num_features = n_features
    extraction.use_gpu = False
    chunk = 8
    for start in range(0, len(names), chunk):
        part = names[start:start + chunk]
        pycolmap.extract_features(db, images.folder, image_names=part, camera_mode=pycolmap.CameraMode.SINGLE,
                                  reader_options=reader, extraction_options=extraction, device=pycolmap.Device.cpu)
        if task is not None:
            task.advance(len(part))
        reader.existing_camera_id = 1  # the later chunks share the first chunk's camera


def _matching_options(options: SfmOptions):
    pycolmap = _pycolmap()
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = options.num_threads
    matching.use_gpu = False
    return matching


def _match_listed(db: Path, names: list[str], pairs: list[tuple[int, int]], options: SfmOptions) -> None:
    """Match the listed pairs (indices into names) with geometric verification (pycolmap's imported pairs)."""
    pycolmap = _pycolmap()
    listing = db.parent / f"pairs_{len(pairs)}.txt"
    listing.write_text("".join(f"{names[i]} {names[j]}\n" for i, j in pairs))
    pycolmap.match_image_pairs(db, matching_options=_matching_options(options),
                               pairing_options=pycolmap.ImportedPairingOptions(match_list_path=listing),
                               device=pycolmap.Device.cpu)


def probe_inliers(images: ImageSet, work_dir: Path, options: SfmOptions, known_K,
                  near: list[tuple[int, int]], far: list[tuple[int, int]]) -> matcher_choice.SequenceProbe:
    """Verified inliers of the pairs near and far (indices into images.names) on probe_num_features features per
    photo, in a database of their own under work_dir (matcher_choice's sequence probe)."""
    pycolmap = _pycolmap()
    work_dir.mkdir(parents=True, exist_ok=True)
    db = work_dir / "probe.db"
    used = sorted({k for pair in near + far for k in pair})
    _extract(db, images, [images.names[k] for k in used], options, known_K, options.probe_num_features)
    _match_listed(db, images.names, near + far, options)
    database = pycolmap.Database.open(str(db))
    try:
        ids = {image.name: image.image_id for image in database.read_all_images()}
        pair_ids, counts = database.read_two_view_geometry_num_inliers()
    finally:
        database.close()
    inliers = dict(zip(pair_ids, counts))

    def count(i, j):
        return int(inliers.get(pycolmap.image_pair_to_pair_id(ids[images.names[i]], ids[images.names[j]]), 0))

    return matcher_choice.SequenceProbe(np.array([count(i, j) for i, j in near], float),
                                        np.array([count(i, j) for i, j in far], float))


def run_sfm(images: ImageSet, work_dir: Path, options: SfmOptions, progress, known_K: np.ndarray | None = None,
            known_centres: dict | None = None):
    """Run SfM on `images` in `work_dir`; return (largest pycolmap.Reconstruction or None, number of models, the
    MatcherChoice it used). The matcher choice and, when auto's sequential matching registers too few photos, the
    exhaustive rerun are printed through progress.log.

    known_K (3,3, OpenCV pixel convention): fixed pinhole intrinsics shared by all photos.
    known_centres: image name -> world centre (m), used only to pick pairs for spatial matching.
    """
    pycolmap = _pycolmap()
    if hasattr(pycolmap, "set_random_seed"):
        pycolmap.set_random_seed(options.seed)
    n = len(images.names)
    all_known = known_centres is not None and all(nm in known_centres for nm in images.names)
    base = choose_matcher(options, n, all_known)
    if base[0] == "spatial" and not all_known:
        raise ConfigError("calibrate.sfm.matcher = 'spatial' needs a known centre (--poses) for every photo")

    def probe(near, far):
        with progress.task("matching: sequence probe", total=1) as task:
            result = probe_inliers(images, work_dir / "probe", options, known_K, near, far)
            task.advance(1)
        return result

    choice = matcher_choice.choose(options, n, base, probe)
    progress.log(f"matching: {choice.matcher} ({choice.reason})")
    rec, n_models = _sfm_with(choice, images, work_dir / "sfm", options, progress, known_K, known_centres)
    registered = 0 if rec is None else rec.num_reg_images()
    if choice.probed and registered < options.sequential_min_registered_fraction * n:
        choice = matcher_choice.fallback(options, n, all_known, registered)
        progress.log(f"matching: {choice.matcher} instead ({choice.reason})")
        rec2, n_models2 = _sfm_with(choice, images, work_dir / "fallback", options, progress, known_K, known_centres)
        if rec2 is not None and rec2.num_reg_images() >= registered:
            rec, n_models = rec2, n_models2
    return rec, n_models, choice


def _sfm_with(choice: matcher_choice.MatcherChoice, images: ImageSet, work_dir: Path, options: SfmOptions, progress,
              known_K, known_centres):
    """Features, matching by `choice` and incremental mapping in work_dir: (largest model or None, models)."""
    pycolmap = _pycolmap()
    work_dir.mkdir(parents=True, exist_ok=True)
    db = work_dir / "database.db"
    with progress.task("features", total=len(images.names)) as task:
        _extract(db, images, images.names, options, known_K, choice.num_features, task)
    matching = _matching_options(options)
    with progress.task(f"matching ({choice.matcher})", total=1) as task:
        if choice.matcher == "exhaustive":
            pycolmap.match_exhaustive(db, matching_options=matching, device=pycolmap.Device.cpu)
        elif choice.matcher == "sequential":
            pairing = pycolmap.SequentialPairingOptions()
            pairing.overlap = options.sequential_overlap
            pairing.quadratic_overlap = True
            pairing.loop_detection = False  # COLMAP's needs a vocabulary tree (a download): keyframes instead
            pycolmap.match_sequential(db, matching_options=matching, pairing_options=pairing,
                                      device=pycolmap.Device.cpu)
            loops = matcher_choice.loop_pairs(len(images.names), options.loop_closure_period, options.sequential_overlap)
            if loops:
                _match_listed(db, images.names, loops, options)
        elif choice.matcher == "spatial":
            _write_position_priors(db, known_centres)
            pairing = pycolmap.SpatialPairingOptions()
            pairing.max_num_neighbors = options.spatial_neighbors
            pairing.ignore_z = False
            pairing.max_distance = 1e9
            pairing.num_threads = options.num_threads
            pycolmap.match_spatial(db, matching_options=matching, pairing_options=pairing,
                                   device=pycolmap.Device.cpu)
        else:
            raise StageError(f"unknown matcher {choice.matcher!r} (expected auto, exhaustive, sequential or spatial)")
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
