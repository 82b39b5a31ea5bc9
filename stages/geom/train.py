"""The training loop of stage `geom`: one photo per step, Adam, schedules, densification, checkpoints.

Each step renders one training view (chosen by a seeded permutation per epoch) through the
tracer and minimises the losses of `losses.py`. The photometric terms are on from the start; the
geometric terms (depth-normal consistency, depth uncertainty, normal smoothness) start at
`geometry_from` (a fraction of the iterations), once the Gaussians roughly cover the surfaces.
The means' learning rate decays exponentially to `lr_means_final` of its start.

A checkpoint (parameters, Adam moments, densification sums, the random generator, the step) is
written every `checkpoint_every` steps; resuming from it continues the very same run.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import torch

from rfir_core.errors import ConfigError, InputFileError, StageError
from rfir_core.progress import NullProgress

from .data import View, camera_rays
from .densify import DensifyStats, densify_and_prune
from .losses import (depth_normal_loss, depth_uncertainty_loss, normal_smoothness_loss, pseudo_normals, ssim,
                     surface_mask)
from .model import GaussianModel
from .gaussian_views import make_scene, render_view


@dataclass
class TrainConfig:
    """Settings of the loop (the [geom] table of configs/geom.toml, flattened; see there)."""

    iterations: int = 600
    lr_means: float = 0.001  # x extent, m per step
    lr_means_final: float = 0.02
    lr_log_scales: float = 0.005
    lr_rotations: float = 0.002
    lr_opacity: float = 0.05
    lr_colors: float = 0.02
    lr_normals: float = 0.01
    w_l1: float = 0.8
    w_ssim: float = 0.2
    w_normal: float = 0.05
    w_depth_uncertainty: float = 0.05
    w_normal_smooth: float = 0.05
    geometry_from: float = 0.3
    densify_every: int = 100
    densify_from: int = 100
    densify_until: float = 0.7
    grow_fraction: float = 0.25
    max_gaussians: int = 40000
    split_scale: float = 0.01  # x extent
    min_opacity: float = 0.01
    max_scale: float = 0.1  # x extent
    rebuild_every: int = 50
    alpha_min: float = 1.0 / 255.0
    checkpoint_every: int = 100
    seed: int = 0

    @classmethod
    def from_table(cls, table: dict, seed: int) -> "TrainConfig":
        names = {f.name for f in fields(cls)}
        kw = {k: v for k, v in table.items() if k in names}
        loss = dict(table.get("loss", {}))
        for key in ("l1", "ssim", "normal", "depth_uncertainty", "normal_smooth"):
            if key in loss:
                kw[f"w_{key}"] = float(loss[key])
        dens = dict(table.get("densify", {}))
        for key, name in (("every", "densify_every"), ("from", "densify_from"), ("until", "densify_until")):
            if key in dens:
                kw[name] = dens.pop(key)
        kw.update({k: v for k, v in dens.items() if k in names})
        cfg = cls(**kw, seed=seed)
        if cfg.iterations < 1:
            raise ConfigError(f"geom.iterations must be >= 1, got {cfg.iterations}")
        for f in fields(cls):
            v = getattr(cfg, f.name)
            if f.name.startswith(("w_", "lr_")) and (not isinstance(v, (int, float)) or v < 0 or not math.isfinite(v)):
                key = f"geom.loss.{f.name[2:]}" if f.name.startswith("w_") else f"geom.{f.name}"
                raise ConfigError(f"{key} must be a finite number >= 0, got {v!r}")
        return cfg


@dataclass
class TrainResult:
    """What the loop did: loss curve [iterations], timings, densification log, resume point."""

    loss_curve: np.ndarray
    terms: dict[str, np.ndarray]
    wall_time_s: float
    resumed_at: int
    densify_log: list[dict]


TERMS = ("l1", "ssim", "normal", "depth_uncertainty", "normal_smooth")


class Trainer:
    """Optimises a GaussianModel on training views. extent_m sets the scale of lengths in the config;
    ref_distance_m normalises the depth-uncertainty term."""

    def __init__(self, model: GaussianModel, views: list[View], background: np.ndarray, cfg: TrainConfig, *,
                 extent_m: float, ref_distance_m: float, device: str = "cpu"):
        self.model, self.cfg, self.device = model, cfg, device
        self.views = [v for v in views if v.split == 0]
        self.extent, self.ref_distance = float(extent_m), float(ref_distance_m)
        self.background = torch.as_tensor(background, dtype=torch.float32, device=device)
        self.rays = [camera_rays(v, device) for v in self.views]
        self.images = [torch.as_tensor(v.image, device=device) for v in self.views]
        self.generator = torch.Generator().manual_seed(cfg.seed)
        self.stats = DensifyStats.zeros(model.num, device)
        self.order: list[int] = []
        self.step = 0
        self.curve: list[float] = []
        self.term_curves: dict[str, list[float]] = {t: [] for t in TERMS}
        self.densify_log: list[dict] = []
        model.lrs = {"means": cfg.lr_means * self.extent, "log_scales": cfg.lr_log_scales,
                     "rotations": cfg.lr_rotations, "opacity_logits": cfg.lr_opacity,
                     "color_logits": cfg.lr_colors, "normals_raw": cfg.lr_normals}
        self.scene = make_scene(model, cfg.alpha_min)

    # ------------------------------------------------------------------ one step
    def _next_view(self) -> int:
        if not self.order:
            self.order = torch.randperm(len(self.views), generator=self.generator).tolist()
        return self.order.pop(0)

    def loss(self, i: int, geometry: bool) -> tuple[torch.Tensor, dict[str, float]]:
        cfg, (origin, dirs), gt = self.cfg, self.rays[i], self.images[i]
        r = render_view(self.scene, self.model, origin, dirs, self.background)
        parts = {"l1": (r.color - gt).abs().mean()}
        if cfg.w_ssim > 0:
            parts["ssim"] = 1.0 - ssim(r.color, gt)
        if geometry and cfg.w_normal > 0:
            pseudo = pseudo_normals(r.expected_depth(), dirs, origin)
            parts["normal"] = depth_normal_loss(r.normal, pseudo, surface_mask(r.acc))
        if geometry and cfg.w_depth_uncertainty > 0:
            parts["depth_uncertainty"] = depth_uncertainty_loss(r.depth, r.depth_sq, self.ref_distance)
        if geometry and cfg.w_normal_smooth > 0:
            parts["normal_smooth"] = normal_smoothness_loss(r.normal, gt)
        weights = {t: getattr(cfg, f"w_{t}") for t in TERMS}
        total = sum(weights[k] * v for k, v in parts.items())
        return total, {k: float(v.detach()) for k, v in parts.items()}

    def train_step(self) -> float:
        cfg, it = self.cfg, self.step
        geometry = it >= int(cfg.geometry_from * cfg.iterations)
        self.model.zero_grad()
        total, parts = self.loss(self._next_view(), geometry)
        if not torch.isfinite(total):
            raise StageError(f"geom: the loss became {float(total)} at step {it}; lower the learning rates")
        total.backward()
        grad = self.model.params["means"].grad
        if grad is not None:
            self.stats.add(grad)
        decay = cfg.lr_means_final ** (it / max(1, cfg.iterations - 1))
        self.model.step({"means": decay})
        self.step += 1
        self.curve.append(float(total.detach()))
        for t in TERMS:
            self.term_curves[t].append(parts.get(t, float("nan")))
        self._maybe_densify()
        if cfg.rebuild_every > 0 and self.step % cfg.rebuild_every == 0:
            self.scene.rebuild()
        return self.curve[-1]

    def _maybe_densify(self) -> None:
        cfg, s = self.cfg, self.step
        if cfg.densify_every <= 0 or s < cfg.densify_from or s > cfg.densify_until * cfg.iterations:
            return
        if s % cfg.densify_every != 0:
            return
        rep = densify_and_prune(self.model, self.stats, grow_fraction=cfg.grow_fraction,
                                max_gaussians=cfg.max_gaussians, split_scale=cfg.split_scale * self.extent,
                                min_opacity=cfg.min_opacity, max_scale=cfg.max_scale * self.extent,
                                generator=self.generator)
        if self.model.num == 0:
            raise StageError("geom: pruning removed every Gaussian; lower geom.densify.min_opacity")
        self.densify_log.append({"step": s, "cloned": rep.cloned, "split": rep.split, "pruned": rep.pruned,
                                 "total": rep.total})
        self.stats = DensifyStats.zeros(self.model.num, self.device)
        self.scene = make_scene(self.model, cfg.alpha_min)

    # ------------------------------------------------------------------ checkpoints
    def save(self, path: Path, key: str) -> None:
        state = {"key": key, "step": self.step, "generator": self.generator.get_state(),
                 "order": torch.tensor(self.order, dtype=torch.int64),
                 "stats.grad_sum": self.stats.grad_sum.cpu(), "stats.count": self.stats.count.cpu(),
                 "curve": torch.tensor(self.curve, dtype=torch.float64),
                 "densify_log": torch.tensor([[d[k] for k in ("step", "cloned", "split", "pruned", "total")]
                                              for d in self.densify_log], dtype=torch.int64).reshape(-1, 5)}
        for t in TERMS:
            state[f"term.{t}"] = torch.tensor(self.term_curves[t], dtype=torch.float64)
        state.update({k: (v.cpu() if isinstance(v, torch.Tensor) else v) for k, v in self.model.state().items()})
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".partial")
        torch.save(state, tmp)
        tmp.replace(path)

    def load(self, path: Path, key: str) -> None:
        try:
            state = torch.load(path, weights_only=True)
        except Exception as exc:  # noqa: BLE001 - a damaged checkpoint is a user-fixable input problem
            raise InputFileError(f"cannot read checkpoint ({exc})", path=path) from None
        if state.get("key") != key:
            raise InputFileError("checkpoint was made for other inputs or settings; delete it or drop --resume", path=path)
        self.model.load_state({k: (v.to(self.device) if isinstance(v, torch.Tensor) else v) for k, v in state.items()
                               if k == "step_count" or k.startswith(("param.", "exp_avg.", "exp_avg_sq."))})
        self.step = int(state["step"])
        self.generator.set_state(state["generator"])
        self.order = state["order"].tolist()
        self.stats = DensifyStats(state["stats.grad_sum"].to(self.device), state["stats.count"].to(self.device))
        self.curve = state["curve"].tolist()
        self.term_curves = {t: state[f"term.{t}"].tolist() for t in TERMS}
        self.densify_log = [dict(zip(("step", "cloned", "split", "pruned", "total"), row))
                            for row in state["densify_log"].tolist()]
        self.scene = make_scene(self.model, self.cfg.alpha_min)

    # ------------------------------------------------------------------ the loop
    def run(self, progress=None, checkpoint: Path | None = None, resume: bool = False, key: str = "") -> TrainResult:
        progress = progress or NullProgress()
        start = 0
        if resume and checkpoint is not None and checkpoint.exists():
            self.load(checkpoint, key)
            start = self.step
            progress.log(f"geom: resumed from {checkpoint} at step {start}")
        t0 = time.time()
        with progress.task("geom: train", total=self.cfg.iterations) as bar:
            bar.advance(start)
            while self.step < self.cfg.iterations:
                self.train_step()
                if checkpoint is not None and self.cfg.checkpoint_every > 0 and self.step % self.cfg.checkpoint_every == 0:
                    self.save(checkpoint, key)
                bar.advance(1)
        return TrainResult(np.asarray(self.curve), {t: np.asarray(v) for t, v in self.term_curves.items()},
                           time.time() - t0, start, list(self.densify_log))
