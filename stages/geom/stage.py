"""`run(...)` of stage `geom`: calib.h5 -> scene.h5 (+ PLY, fused mesh, held-out renders, metrics).

1. Load the calibrated photos at training resolution; hold every `test_every`-th out.
2. Start one flat Gaussian per sparse SfM point (init.py), train through the tracer (train.py).
3. Render every view; turn the normals towards the cameras that see them; score the held-out views.
4. Fuse the rendered depth into a mesh (tsdf.py); compare with a ground-truth mesh when there is one.
5. Write SCENE.ply, SCENE_mesh.ply, SCENE_renders/ and, last, the `scene` artifact.
"""
from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from rfir_core.artifacts import read_artifact, write_artifact
from rfir_core.errors import ConfigError, InputFileError
from rfir_core.progress import NullProgress
from rfir_core.provenance import Provenance, sha256_file

from .data import background_colour, load_views
from .evaluate import gt_mesh_metrics, image_metrics, orient_normals, render_all, write_pngs
from .init import init_from_points
from .model import GaussianModel, as_numpy_fields
from .train import TrainConfig, Trainer


@dataclass
class GeomResult:
    """Paths written, sizes, metrics (see evaluate.py) and timings (s)."""

    path: Path
    num_gaussians: int
    num_init: int
    num_train_views: int
    num_test_views: int
    image_size: tuple[int, int]
    metrics: dict[str, float]
    timings_s: dict[str, float]
    ply_path: Path | None = None
    mesh_path: Path | None = None
    renders_dir: Path | None = None
    gt_mesh: Path | None = None
    resumed_at: int = 0
    notes: list[str] = field(default_factory=list)


def side_paths(out_path: Path) -> tuple[Path, Path, Path]:
    """(Gaussian PLY, fused mesh PLY, renders folder) written beside the artifact."""
    stem = out_path.with_suffix("")
    return stem.with_suffix(".ply"), stem.with_name(stem.name + "_mesh.ply"), stem.with_name(stem.name + "_renders")


def find_gt_mesh(setting: str, calib, calib_path: Path) -> Path | None:
    """The ground-truth mesh named by geom.evaluate.gt_mesh ("auto": <photos>/../meshes/*_gt.ply)."""
    if setting == "":
        return None
    if setting != "auto":
        path = Path(setting)
        if not path.is_file():
            raise InputFileError("ground-truth mesh not found (geom.evaluate.gt_mesh / --gt-mesh)", path=path)
        return path
    first = Path(str(calib["image_paths"][0]))
    if not first.is_absolute():
        first = calib_path.parent / first
    found = sorted((first.parent.parent / "meshes").glob("*_gt.ply"))
    return found[0] if len(found) == 1 else None


def run(calib_path, out_path, config: dict, *, seed: int = 0, device: str = "cpu", config_toml: str = "",
        progress=None, checkpoint: Path | None = None, resume: bool = False) -> GeomResult:
    """Train Gaussians with normals on a `calib` artifact; config: the [geom] table."""
    progress = progress or NullProgress()
    t_start = time.time()
    calib_path, out_path = Path(calib_path), Path(out_path)
    if out_path.exists() and out_path.resolve() == calib_path.resolve():
        raise ConfigError(f"-o {out_path} would overwrite the input")
    out_cfg, eval_cfg = dict(config.get("output", {})), dict(config.get("evaluate", {}))
    cfg = TrainConfig.from_table(config, seed)
    _check_settings(config)
    torch.manual_seed(seed)
    calib = read_artifact(calib_path, "calib")
    gt_path = find_gt_mesh(str(eval_cfg.get("gt_mesh", "auto")), calib, calib_path)
    timings: dict[str, float] = {}
    notes: list[str] = []

    t0 = time.time()
    views = load_views(calib, calib_path, int(config.get("max_image_width", 240)), int(config.get("test_every", 8)))
    bg_cfg = list(config.get("background", []))
    if bg_cfg and (len(bg_cfg) != 3 or not all(0 <= float(c) <= 1 for c in bg_cfg)):
        raise ConfigError(f"geom.background must be [] or three numbers in [0, 1], got {bg_cfg}")
    background = np.asarray(bg_cfg, dtype=np.float32) if bg_cfg else background_colour(views)
    cams = np.stack([v.centre for v in views])
    init = init_from_points(calib["points_xyz"], calib["points_rgb"], cams,
                            max_points=int(config.get("max_init_points", 20000)),
                            init_opacity=float(config.get("init_opacity", 0.3)),
                            thickness_ratio=float(config.get("init_thickness", 0.3)), seed=seed, where=str(calib_path))
    ref_distance = float(np.median(np.linalg.norm(cams - init.centre, axis=1)))
    timings["load"] = time.time() - t0
    progress.log(f"geom: {len(views)} views at {views[0].width} x {views[0].height} px "
                 f"({sum(v.split == 1 for v in views)} held out), {init.num_points} Gaussians from sparse points, "
                 f"extent {init.extent_m:.3g} m, device {device}")

    model = GaussianModel(init.params, {}).to(device)
    trainer = Trainer(model, views, background, cfg, extent_m=init.extent_m, ref_distance_m=ref_distance, device=device)
    ckpt = Path(checkpoint) if checkpoint is not None else out_path.with_name(out_path.name + ".ckpt.pt")
    key = _key(sha256_file(calib_path), {k: v for k, v in config.items() if k not in ("checkpoint_every", "output",
                                                                                           "evaluate")}, seed)
    train = trainer.run(progress, checkpoint=ckpt, resume=resume, key=key)
    model = trainer.model
    timings["train"] = train.wall_time_s

    t0 = time.time()
    with progress.task("geom: render views", total=len(views)) as bar:
        maps = render_all(model, views, background, cfg.alpha_min, device, bar)
    flipped = orient_normals(model, views, maps)
    fields = as_numpy_fields(model)
    metrics = image_metrics(views, maps)
    timings["render"] = time.time() - t0

    ply_path, mesh_path, renders_dir = side_paths(out_path)
    fused_v = fused_f = None
    t0 = time.time()
    if bool(out_cfg.get("mesh", True)):
        from .tsdf import fuse_tsdf, mesh_arrays, write_mesh

        mesh = fuse_tsdf(views, maps, float(out_cfg.get("tsdf_voxel", 0.005)) * init.extent_m,
                         float(out_cfg.get("tsdf_trunc_voxels", 4.0)))
        fused_v, fused_f = mesh_arrays(mesh)
        if len(fused_f):
            write_mesh(mesh_path, mesh)
        else:
            notes.append("the fused mesh is empty (too few views agree at this voxel size); no mesh written, "
                         "try a larger geom.output.tsdf_voxel")
            mesh_path, fused_v, fused_f = None, None, None
    else:
        mesh_path = None
    timings["mesh"] = time.time() - t0
    if gt_path is not None:
        t0 = time.time()
        metrics.update(gt_mesh_metrics(gt_path, views, maps, fields, fused_v, fused_f,
                                       num_points=int(eval_cfg.get("chamfer_points", 100000)), seed=seed))
        timings["evaluate"] = time.time() - t0
    if bool(out_cfg.get("ply", True)):
        from .export_ply import write_gaussian_ply

        write_gaussian_ply(ply_path, fields)
    else:
        ply_path = None
    if bool(out_cfg.get("renders", True)) and any(v.split == 1 for v in views):
        write_pngs(renders_dir, views, maps)
    else:
        renders_dir = None
    metrics["num_gaussians"] = model.num

    timings["total"] = time.time() - t_start
    prov = Provenance(stage="geom", config_toml=config_toml, device=device)
    prov.add_input(calib_path)
    if gt_path is not None:
        prov.add_input(gt_path)
    prov.wall_time_s = timings["total"]
    prov.extra = {"seed": seed, "timings_s": timings, "background": background.tolist(), "extent_m": init.extent_m,
                  "resumed_at": train.resumed_at, "normals_flipped": flipped, "notes": notes}
    training = {"loss": train.loss_curve, **{f"loss_{k}": v for k, v in train.terms.items()},
                "test_views": np.asarray([v.name for v in views if v.split == 1], dtype=object),
                "@attrs": {"metrics_json": json.dumps(metrics, sort_keys=True),
                           "densify_json": json.dumps(train.densify_log), "iterations": cfg.iterations,
                           "image_width": views[0].width, "image_height": views[0].height,
                           "num_init": init.num_points}}
    attrs = {"source": str(calib_path)}
    write_artifact(out_path, "scene", fields, attrs=attrs, provenance=prov, free={"training": training})
    return GeomResult(out_path, model.num, init.num_points, sum(v.split == 0 for v in views),
                      sum(v.split == 1 for v in views), (views[0].width, views[0].height), metrics, timings,
                      ply_path, mesh_path, renders_dir, gt_path, train.resumed_at, notes)


def _check_settings(config: dict) -> None:
    """Refuse values outside their ranges before any work (ConfigError naming the key)."""
    checks = [("max_image_width", lambda v: v == 0 or v >= 32, "0 (full size) or >= 32 px"),
              ("test_every", lambda v: v >= 0 and v != 1, "0 or >= 2"), ("max_init_points", lambda v: v >= 0, ">= 0"),
              ("init_opacity", lambda v: 0 < v < 1, "in (0, 1)"), ("init_thickness", lambda v: v > 0, "> 0")]
    for key, ok, want in checks:
        if key in config and not ok(config[key]):
            raise ConfigError(f"geom.{key} must be {want}, got {config[key]!r}")
    voxel = dict(config.get("output", {})).get("tsdf_voxel", 0.005)
    if not voxel > 0:
        raise ConfigError(f"geom.output.tsdf_voxel must be > 0, got {voxel!r}")


def _key(*parts) -> str:
    return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]
