"""rfir_stages.calibrate.run: photos -> SfM (or an imported COLMAP model) -> metric alignment -> calib.h5."""
from __future__ import annotations

import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from rfir_core.errors import ConfigError, InputFileError, StageError
from rfir_core.progress import NullProgress, Progress

from . import sfm as sfm_mod
from .align import Alignment, CentreReferences, align_to_centres, align_to_points, load_centre_references, \
    load_point_references
from .images import ImageSet, scan_images
from .model import SfmModel, from_reconstruction


@dataclass
class CalibrateOptions:
    """Settings of section [calibrate] in configs/calibrate.toml (see the comments there)."""

    min_registered_fraction: float = 0.5
    alignment_threshold_m: float = 0.05
    alignment_use_rotations: bool = True
    alignment_warn_rms_m: float = 0.02
    drop_reference_outliers: bool = True
    centre_prior_m: float = 0.001
    refine_loss_scale_px: float = 0.5
    reference_subset: int = 0
    marker_dictionary: str = "DICT_4X4_50"
    keep_model: bool = True
    plot: bool = True
    sfm: sfm_mod.SfmOptions = field(default_factory=sfm_mod.SfmOptions)

    @classmethod
    def from_config(cls, section: dict, seed: int = 0) -> "CalibrateOptions":
        """Build from the resolved [calibrate] table (unknown keys were already refused by the loader)."""
        section = dict(section or {})
        sfm_table = dict(section.pop("sfm", {}) or {})
        names = {f.name for f in fields(cls)}
        sfm_names = {f.name for f in fields(sfm_mod.SfmOptions)}
        for key in list(section) + list(sfm_table):
            if key not in names | sfm_names:
                raise ConfigError(f"unknown calibrate setting {key!r}")
        sfm_opts = sfm_mod.SfmOptions(**{k: v for k, v in sfm_table.items() if k in sfm_names}, seed=seed)
        return cls(**{k: v for k, v in section.items() if k in names and k != "sfm"}, sfm=sfm_opts)


@dataclass
class CalibrateInputs:
    """What to calibrate and against what.

    images: folder of photos; out: the calib.h5 to write; poses: camera centres (a `cameras` .h5
    or a name,x,y,z CSV); points: known 3D points CSV; markers: ArUco layout CSV; intrinsics_from:
    a `cameras` .h5 whose (shared) K is used and kept fixed; colmap_model: import this model instead
    of running SfM; no_metric: allow an artifact without metric scale; subset: use only this many
    pose references (overrides the config; None keeps it).
    """

    images: Path
    out: Path
    poses: Path | None = None
    points: Path | None = None
    markers: Path | None = None
    intrinsics_from: Path | None = None
    colmap_model: Path | None = None
    no_metric: bool = False
    subset: int | None = None


@dataclass
class CalibResult:
    """What calibrate did: counts, errors, the alignment, where it wrote, how long each phase took, and the SfM
    matcher it used with the reason ("" for an imported model)."""

    out: Path
    n_images: int
    n_registered: int
    unregistered: list[str]
    mean_reproj_px: float
    n_points: int
    metric: bool
    alignment: Alignment | None
    camera_model: str
    plot_path: Path | None = None
    model_dir: Path | None = None
    undistorted_dir: Path | None = None
    timings_s: dict = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)
    matcher: str = ""

    @property
    def registered_fraction(self) -> float:
        return self.n_registered / max(self.n_images, 1)


def _known_intrinsics(path: Path, images: ImageSet) -> np.ndarray:
    from rfir_core.artifacts import read_artifact

    art = read_artifact(path, "cameras")
    Ks = np.asarray(art.data["intrinsics"], float)
    sizes = np.asarray(art.data["image_size"])
    if not np.allclose(Ks, Ks[0], rtol=1e-6, atol=1e-6):
        raise InputFileError("the cameras have different intrinsics; calibrate supports one shared camera", path=path)
    if not np.all(sizes == (images.width, images.height)):
        w, h = sizes[0]
        raise InputFileError(f"intrinsics are for {w}x{h} images but the photos are {images.width}x{images.height}",
                             path=path)
    return Ks[0]


def _check_reference_names(refs_names: list[str], images: ImageSet, source: str, warnings: list[str]) -> None:
    present = set(images.names)
    missing = [n for n in refs_names if n not in present]
    if len(refs_names) - len(missing) < 3:
        shown = ", ".join(missing[:5]) + (" ..." if len(missing) > 5 else "")
        raise InputFileError(f"{len(missing)} of {len(refs_names)} references name images that are not in "
                             f"{images.folder} ({shown}); metric alignment needs at least 3 that are", path=source)
    if missing:
        warnings.append(f"{len(missing)} of {len(refs_names)} references in {source} name images not in the folder "
                        "(ignored)")


def _sfm_or_import(inputs: CalibrateInputs, images: ImageSet, options: CalibrateOptions, work: Path, progress,
                   known_K, known_centres: dict | None = None) -> tuple[object, int, str]:
    """(reconstruction or None, number of models, the matcher used and why: "" for an imported model)."""
    if inputs.colmap_model is not None:
        rec = sfm_mod.read_colmap_model(inputs.colmap_model)
        names = [rec.image(i).name for i in rec.reg_image_ids()]
        absent = [n for n in names if n not in set(images.names)]
        if absent:
            raise InputFileError(f"the COLMAP model has {len(absent)} image(s) that are not in {images.folder}: "
                                 f"{', '.join(absent[:5])}", path=inputs.colmap_model)
        return rec, 1, ""
    rec, n_models, choice = sfm_mod.run_sfm(images, work, options.sfm, progress, known_K=known_K,
                                            known_centres=known_centres)
    return rec, n_models, f"{choice.matcher} ({choice.reason})"


def _registration_error(n_reg: int, n: int, n_models: int, need: float) -> StageError:
    tips = ("try: photos with more overlap (neighbouring photos should share most of their view), more texture, "
            "a higher resolution, or --set calibrate.sfm.matcher=exhaustive")
    models = f" in {n_models} separate models" if n_models > 1 else ""
    return StageError(f"structure from motion registered {n_reg} of {n} images{models} (need {need:.0%}); {tips}")


def run(inputs: CalibrateInputs, options: CalibrateOptions | None = None, progress: Progress | None = None, *,
        config_toml: str = "") -> CalibResult:
    """Calibrate the photos in inputs.images and write inputs.out (a `calib` artifact).

    Raises InputFileError for bad inputs, ConfigError for a missing metric reference (unless
    no_metric), StageError when SfM registers too few images or the alignment fails. Nothing is
    written unless everything succeeds.
    """
    options = options or CalibrateOptions()
    progress = progress or NullProgress()
    timings: dict[str, float] = {}
    warnings: list[str] = []
    t0 = time.time()
    if sum(x is not None for x in (inputs.poses, inputs.points, inputs.markers)) > 1:
        raise ConfigError("give only one metric reference: --poses, --points or --markers")
    if inputs.poses is None and inputs.points is None and inputs.markers is None and not inputs.no_metric:
        raise ConfigError("no metric reference: give --poses (cameras.h5 or name,x,y,z CSV), --points or --markers, "
                          "or --no-metric to write an artifact in arbitrary SfM units")
    options.sfm.check()
    images = scan_images(inputs.images)
    centre_refs: CentreReferences | None = None
    point_refs = None
    if inputs.poses is not None:
        subset = options.reference_subset if inputs.subset is None else inputs.subset
        centre_refs = load_centre_references(inputs.poses, subset)
        _check_reference_names(centre_refs.names, images, str(inputs.poses), warnings)
    elif inputs.points is not None:
        point_refs = load_point_references(inputs.points)
        seen_in = sorted({o[0] for obs in point_refs.observations for o in obs})
        absent = [nm for nm in seen_in if nm not in set(images.names)]
        if absent:
            warnings.append(f"{len(absent)} image(s) named in {inputs.points} are not in the folder: "
                            f"{', '.join(absent[:5])}")
    if options.sfm.matcher == "spatial" and inputs.colmap_model is None and (
            centre_refs is None or not set(images.names) <= set(centre_refs.names)):
        raise ConfigError("calibrate.sfm.matcher = 'spatial' needs --poses with the centre of every photo "
                          "(and no --subset); use auto, exhaustive or sequential")
    known_K = _known_intrinsics(inputs.intrinsics_from, images) if inputs.intrinsics_from is not None else None
    timings["check_inputs"] = time.time() - t0

    with tempfile.TemporaryDirectory(prefix="rfir-calibrate-") as tmp:
        work = Path(tmp)
        t = time.time()
        known_centres = dict(zip(centre_refs.names, centre_refs.centres)) if centre_refs is not None else None
        rec, n_models, matcher = _sfm_or_import(inputs, images, options, work, progress, known_K, known_centres)
        timings["sfm" if inputs.colmap_model is None else "import"] = time.time() - t
        n = len(images.names)
        n_reg = 0 if rec is None else rec.num_reg_images()
        if rec is None or n_reg < max(3, options.min_registered_fraction * n):
            raise _registration_error(n_reg, n, n_models, options.min_registered_fraction)
        if n_models > 1:
            warnings.append(f"SfM split the photos into {n_models} models; kept the largest ({n_reg} images)")
        staged_model = None
        if options.keep_model and inputs.colmap_model is None:
            staged_model = work / "colmap_model"
            sfm_mod.write_colmap_model(rec, staged_model)

        t = time.time()
        with progress.task("markers" if inputs.markers else "alignment", total=1) as task:
            if inputs.markers is not None:
                from .markers import marker_references

                point_refs = marker_references(images, inputs.markers, options.marker_dictionary)
            alignment = _align(rec, centre_refs, point_refs, options)
            task.advance(1)
        timings["alignment"] = time.time() - t
        refined_from = np.eye(4)  # SfM frame -> the frame rec is in (the world frame after refinement)
        if alignment is not None and centre_refs is not None and options.centre_prior_m > 0:
            # bundle adjustment with the known centres pinned (in the world frame), then align again
            t = time.time()
            with progress.task("refinement", total=1) as task:
                keep = [lab for lab, ok in zip(alignment.labels, alignment.inliers) if ok]
                index = {nm: k for k, nm in enumerate(centre_refs.names)}
                sfm_mod.refine_with_centre_priors(rec, alignment.sim3, keep,
                                                  centre_refs.centres[[index[nm] for nm in keep]],
                                                  options.centre_prior_m, refine_intrinsics=known_K is None,
                                                  num_threads=options.sfm.num_threads,
                                                  loss_scale_px=options.refine_loss_scale_px)
                first = alignment
                refined_from = first.sim3
                alignment = _align(rec, centre_refs, point_refs, options)
                alignment.warnings = list(dict.fromkeys(first.warnings + alignment.warnings))
                task.advance(1)
            timings["refinement"] = time.time() - t
        if alignment is not None:
            warnings += alignment.warnings
            rms = float(np.sqrt(np.mean(alignment.residuals_m[alignment.inliers] ** 2)))
            if rms > options.alignment_warn_rms_m:
                warnings.append(f"alignment RMS residual {rms * 100:.1f} cm exceeds "
                                f"{options.alignment_warn_rms_m * 100:.1f} cm: check the references")

        t = time.time()
        staged_undistorted = None
        distortion = sfm_mod.max_distortion_px(rec)
        image_folder = images.folder
        if distortion <= options.sfm.max_ignored_distortion_px:
            sfm_mod.drop_distortion(rec)
        else:
            with progress.task("undistortion", total=1) as task:
                dist_model = work / "distorted_model"
                sfm_mod.write_colmap_model(rec, dist_model)
                staged_undistorted = work / "undistorted"
                names = [rec.image(i).name for i in rec.reg_image_ids()]
                rec = sfm_mod.undistort(dist_model, images.folder, staged_undistorted, names)
                image_folder = staged_undistorted / "images"
                task.advance(1)
        timings["undistortion"] = time.time() - t
        model = from_reconstruction(rec)
        dropped: list[str] = []
        if alignment is not None and centre_refs is not None and options.drop_reference_outliers:
            # a camera far from its known centre was registered wrongly (e.g. a symmetric view)
            dropped = [lab for lab, ok in zip(alignment.labels, alignment.inliers) if not ok]
            if dropped:
                model = model.without(set(dropped))
                warnings.append(f"dropped {len(dropped)} image(s) whose camera is more than "
                                f"{options.alignment_threshold_m:g} m from its reference (wrongly registered): "
                                f"{', '.join(dropped[:5])}")
        metric = alignment is not None
        sim3 = alignment.sim3 if metric else np.eye(4)
        world = model.transformed(sim3)

        out = Path(inputs.out)
        out_dir = out.parent if str(out.parent) else Path(".")
        final_model = out_dir / f"{out.stem}_colmap" if staged_model is not None else None
        final_undist = out_dir / f"{out.stem}_undistorted" if staged_undistorted is not None else None
        final_images = (final_undist / "images") if final_undist is not None else image_folder
        registered = set(str(x) for x in model.names)
        unregistered = [nm for nm in images.names if nm not in registered]
        # alignment_sim3 maps the raw SfM model (calib_colmap/) to the world frame
        data, attrs = _artifact_data(world, final_images, image_folder, out_dir, sim3 @ refined_from, alignment,
                                     metric)
        from rfir_core.artifacts import check_data, write_artifact
        from rfir_core.provenance import Provenance

        problems = check_data("calib", data, attrs, str(out))
        if problems:
            raise StageError("internal: calibration result breaks the schema: " + problems[0])
        # everything is known to be good: move the side outputs into place, then write the artifact
        for staged, final in ((staged_model, final_model), (staged_undistorted, final_undist)):
            if staged is not None:
                if final.exists():
                    shutil.rmtree(final)
                final.parent.mkdir(parents=True, exist_ok=True)
                shutil.move(str(staged), str(final))
        prov = Provenance(stage="calibrate", config_toml=config_toml, extra={
            "timings_s": timings, "unregistered": unregistered, "n_models": n_models, "dropped": dropped,
            "matcher": matcher,
            "camera_model": model.camera_model, "distortion_px": distortion, "warnings": warnings,
            "alignment_method": alignment.method if alignment else "none",
            "alignment_labels": alignment.labels if alignment else [],
            "colmap_model": str(inputs.colmap_model or ""),
        })
        for ref in (inputs.poses, inputs.points, inputs.markers, inputs.intrinsics_from):
            if ref is not None:
                prov.add_input(ref)
        write_artifact(out, "calib", data, attrs=attrs, provenance=prov)
        plot_path = None
        if options.plot:
            from .plot import plot_top_view

            refs_xyz = centre_refs.centres if centre_refs is not None else None
            title = (f"{out.name}: {len(world.names)}/{n} cameras, {len(world.points_xyz)} points"
                     + ("" if metric else " (no metric scale)"))
            plot_path = plot_top_view(out.with_suffix(".png"), world.world_from_camera, world.points_xyz,
                                      world.points_rgb, title, metric, refs_xyz if metric else None)
    timings["total"] = time.time() - t0
    return CalibResult(out, n, len(world.names), unregistered, float(np.mean(world.reproj_error_px)),
                       len(world.points_xyz), metric, alignment, model.camera_model, plot_path, final_model,
                       final_undist, timings, warnings, matcher)


def _align(rec, centre_refs, point_refs, options: CalibrateOptions) -> Alignment | None:
    seed = options.sfm.seed
    if centre_refs is not None:
        raw = from_reconstruction(rec, errors=False)
        return align_to_centres(raw.names, raw.world_from_camera, centre_refs, options.alignment_threshold_m,
                                options.alignment_use_rotations, seed)
    if point_refs is not None:
        def lookup(name):
            P = sfm_mod.cam_from_world(rec, name)
            if P is None:
                return None
            return P, lambda uv: sfm_mod.camera_from_image(rec, name, uv)

        return align_to_points(lookup, point_refs, options.alignment_threshold_m, seed)
    return None


def _artifact_data(world: SfmModel, final_images: Path, hash_folder: Path, out_dir: Path, sim3: np.ndarray,
                   alignment: Alignment | None, metric: bool) -> tuple[dict, dict]:
    from rfir_core.provenance import sha256_file

    paths, hashes = [], []
    for name in world.names:
        target = final_images / str(name)
        try:
            rel = os.path.relpath(target.resolve(), out_dir.resolve())
        except ValueError:  # another drive (Windows)
            rel = str(target.resolve())
        paths.append(rel)
        hashes.append(sha256_file(hash_folder / str(name)))
    data = {
        "image_paths": np.array(paths), "image_sha256": np.array(hashes),
        "image_size": world.image_size.astype(np.int64), "intrinsics": world.intrinsics,
        "world_from_camera": world.world_from_camera, "reproj_error_px": world.reproj_error_px,
        "points_xyz": world.points_xyz, "points_rgb": world.points_rgb.astype(np.uint8),
        "points_track_length": world.points_track_length.astype(np.int64), "alignment_sim3": sim3,
    }
    if alignment is not None:
        data["alignment_residuals_m"] = alignment.residuals_m
    attrs = {"metric": bool(metric), "images_folder": str(final_images.resolve()),
             "alignment_method": alignment.method if alignment else "none"}
    return data, attrs
