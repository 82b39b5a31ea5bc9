"""Fitting the RF attributes to measured path gains with Adam (geometry frozen, cache reused).

Loss (config `loss`), over training links and frequencies, in dB of path gain
(pred_db = 10 log10(|S|^2) + s_tx_db):
- "db_mse" (default): mean (pred_db - meas_db)^2. The metric is an MAE in dB, and RCS spans
  tens of dB over aspect; a linear-power loss (the paper's |S^2 - RSSI|^2) is dominated by the few
  specular flashes and leaves the rest of the pattern unconstrained.
- "db_huber": smooth L1 in dB (beta `huber_db`), less pulled by deep nulls.
- "paper": mean |P_pred - P_meas|^2 / mean P_meas^2 in linear power (the paper's loss, scaled).

Predicted power enters the logarithm with the prediction floor FLOOR_DB added (a link that sees
no Gaussian scores at -250 dB, never at -3000 dB); how many entries sit at the floor is counted.

The state kept is the best one seen, not the last step: the lowest validation MAE when a
validation set is given (model selection), else the lowest training loss (a refit never ends
worse on its training rows than where it started).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch

from rfir_cli.errors import ConfigError, InputFileError
from rfir_cli.progress import NullProgress

from rfir_stages.model.predict import FLOOR_DB

from .params import RFParams
from .render import RenderCache, render_power

LOSSES = ("db_mse", "db_huber", "paper")


@dataclass
class FitConfig:
    """Optimiser settings (the [rf_fit] keys of the same names)."""

    iterations: int = 400
    lr: float = 0.1
    s_tx_lr: float = 0.5
    loss: str = "db_mse"
    huber_db: float = 1.0
    learn: tuple = ("opacity", "roughness", "gamma_abs", "gamma_phase", "s_tx", "diffuse", "diffuse_roughness")
    init_opacity: float = 0.9
    init_roughness: float = 4.0
    init_gamma_abs: float = 0.5
    init_gamma_phase_rad: float = 0.0
    sharing: str = "gaussian"
    diffuse: bool = True
    init_diffuse: float = 0.12
    init_diffuse_roughness: float = 2.0
    checkpoint_every: int = 50
    seed: int = 0

    def __post_init__(self):
        if self.loss not in LOSSES:
            raise ConfigError(f"rf_fit.loss = {self.loss!r}: expected one of {', '.join(LOSSES)}")
        if self.iterations < 0 or self.lr <= 0:
            raise ConfigError("rf_fit.iterations must be >= 0 and rf_fit.lr > 0")


@dataclass
class FitResult:
    """What a fit produced. Arrays are numpy; dB are path-gain dB."""

    opacity: np.ndarray          # [G]
    roughness: np.ndarray        # [G]
    gamma_abs: np.ndarray        # [G]
    gamma_phase_rad: np.ndarray  # [G] wrapped to (-pi, pi]
    s_tx_db: np.ndarray          # [K]
    diffuse: np.ndarray | None   # [G] or None (no diffuse term)
    diffuse_roughness: np.ndarray | None
    loss_curve: np.ndarray       # [iterations]
    train_mae_db: float
    initial_mae_db: float
    iterations: int
    wall_time_s: float
    resumed_at: int = 0
    extra: dict = field(default_factory=dict)


FLOOR_POWER = 10 ** (FLOOR_DB / 10)


def predict_db(cache: RenderCache, params: RFParams) -> torch.Tensor:
    """Predicted path gain [M, K] in dB, >= FLOOR_DB + s_tx_db (the floor keeps the loss finite and smooth)."""
    power = render_power(cache, params.materials())
    return 10 * torch.log10(power + FLOOR_POWER) + params.s_tx_db[None]


def floored(cache: RenderCache, params: RFParams) -> int:
    """How many predicted entries [M, K] are at the prediction floor (power below FLOOR_DB)."""
    with torch.no_grad():
        return int((render_power(cache, params.materials()) < FLOOR_POWER).sum())


def loss_fn(pred_db: torch.Tensor, meas_db: torch.Tensor, kind: str, huber_db: float = 1.0) -> torch.Tensor:
    if kind == "db_mse":
        return ((pred_db - meas_db) ** 2).mean()
    if kind == "db_huber":
        return torch.nn.functional.smooth_l1_loss(pred_db, meas_db, beta=huber_db)
    p, m = 10 ** (pred_db / 10), 10 ** (meas_db / 10)
    return ((p - m) ** 2).mean() / (m**2).mean()


def init_system_gain(cache: RenderCache, params: RFParams, meas_db: torch.Tensor) -> None:
    """Set s_tx_db so that the median prediction matches the median measurement per frequency."""
    with torch.no_grad():
        params.s_tx_db.zero_()
        pred = predict_db(cache, params)
        params.s_tx_db.copy_(torch.nanmedian(meas_db - pred, dim=0).values)


def _save(path: Path, params: RFParams, opt, it: int, curve: list, key: str, best: tuple) -> None:
    """Written to a temporary file and renamed: a kill leaves the previous checkpoint whole."""
    tmp = path.with_name(path.name + ".partial")
    torch.save({"params": params.state_dict(), "opt": opt.state_dict(), "iteration": it,
                "curve": torch.tensor(curve, dtype=torch.float64), "key": key,
                "best_score": float(best[0]), "best_step": int(best[1]), "best_state": best[2]}, tmp)
    tmp.replace(path)


def _load(path: Path, params: RFParams, opt, key: str) -> tuple[int, list, tuple | None]:
    try:
        state = torch.load(path, weights_only=True)
    except Exception as exc:  # noqa: BLE001 - a damaged checkpoint is a user-fixable input problem
        raise InputFileError(f"cannot read checkpoint ({exc})", path=path) from None
    if state.get("key") != key:
        raise InputFileError("checkpoint was made for other inputs or settings; delete it or drop --resume",
                             path=path)
    params.load_state_dict(state["params"])
    opt.load_state_dict(state["opt"])
    best = (state["best_score"], state["best_step"], state["best_state"]) if "best_state" in state else None
    return int(state["iteration"]), state["curve"].tolist(), best


def _snapshot(params: RFParams) -> dict:
    return {k: v.detach().clone() for k, v in params.state_dict().items()}


def fit(cache: RenderCache, meas_db: np.ndarray, params: RFParams, cfg: FitConfig, *, progress=None,
        checkpoint: Path | None = None, resume: bool = False, key: str = "", init_gain: bool = True,
        validation: tuple[RenderCache, np.ndarray] | None = None, eval_every: int = 5) -> FitResult:
    """Optimise `params` so that predicted path gain [M, K] dB matches `meas_db` [M, K].

    init_gain: set the system gain from the medians first (False: `params` is a warm start).
    validation: (cache, measured dB [V, K]) of held-out links: the state with the lowest validation
    MAE (checked every `eval_every` steps and at the end) is kept; without it, the state with the
    lowest training loss. `params` holds the kept state on return."""
    progress = progress or NullProgress()
    torch.manual_seed(cfg.seed)
    target = torch.as_tensor(meas_db, dtype=torch.float64)
    groups = params.groups(list(cfg.learn))
    for g in groups:
        g["lr"] = cfg.s_tx_lr if g["name"] == "s_tx" else cfg.lr
    opt = torch.optim.Adam(groups)
    start, curve, best = 0, [], None
    t0 = time.time()
    if resume and checkpoint is not None and checkpoint.exists():
        start, curve, best = _load(checkpoint, params, opt, key)
        progress.log(f"resumed from {checkpoint} at iteration {start}")
    elif init_gain:
        init_system_gain(cache, params, target)
    with torch.no_grad():
        initial = float((predict_db(cache, params) - target).abs().mean())
    val_target = None if validation is None else torch.as_tensor(validation[1], dtype=torch.float64)

    def val_mae() -> float:
        with torch.no_grad():
            return float((predict_db(validation[0], params) - val_target).abs().mean())

    # the kept state: (score, step, state); a resumed fit starts from the checkpoint's state
    best = best or (val_mae() if validation is not None else math.inf, start, _snapshot(params))
    # Gradient mass per parameter group: groups that never receive any were never seen by a
    # training link (hidden faces); stage.py gives them their neighbours' materials (unseen.py).
    exposure = torch.zeros_like(params.theta_g)
    with progress.task("rf-fit", total=cfg.iterations) as bar:
        bar.advance(start)
        for it in range(start, cfg.iterations):
            opt.zero_grad()
            loss = loss_fn(predict_db(cache, params), target, cfg.loss, cfg.huber_db)
            if not torch.isfinite(loss):
                raise FloatingPointError(f"loss became {float(loss)} at iteration {it}")
            if validation is not None:
                if (it - start) % eval_every == 0 and (score := val_mae()) < best[0]:
                    best = (score, it, _snapshot(params))
            elif float(loss.detach()) < best[0]:   # the loss of the state before this step
                best = (float(loss.detach()), it, _snapshot(params))
            loss.backward()
            for theta in (params.theta_a, params.theta_g, params.theta_d):
                if theta.grad is not None:
                    exposure += theta.grad.abs()
            opt.step()
            curve.append(float(loss.detach()))
            bar.update(loss=curve[-1])   # shown beside the bar, and in the plain lines of a log
            bar.advance(1)
            if checkpoint is not None and cfg.checkpoint_every > 0 and (it + 1) % cfg.checkpoint_every == 0:
                _save(checkpoint, params, opt, it + 1, curve, key, best)
    with torch.no_grad():
        end = val_mae() if validation is not None else float(loss_fn(predict_db(cache, params), target, cfg.loss,
                                                                             cfg.huber_db))
    if end > best[0]:    # an earlier state was better: keep it, not the last step
        params.load_state_dict(best[2])
    best_step = best[1] if end > best[0] else cfg.iterations
    with torch.no_grad():
        mats = params.materials()
        train_mae = float((predict_db(cache, params) - target).abs().mean())
    extra = {"best_step": best_step, "floored": floored(cache, params)}
    if validation is not None:
        extra["val_mae_db"] = min(end, best[0])
    if cfg.iterations > start:
        extra["exposure"] = exposure[params.index].numpy().copy()
    return FitResult(
        opacity=mats.opacity.numpy().copy(), roughness=mats.roughness.numpy().copy(),
        gamma_abs=mats.gamma.abs().numpy().copy(), gamma_phase_rad=np.angle(mats.gamma.numpy()),
        s_tx_db=params.s_tx_db.detach().numpy().copy(),
        diffuse=None if mats.diffuse is None else mats.diffuse.numpy().copy(),
        diffuse_roughness=None if mats.diffuse_roughness is None else mats.diffuse_roughness.numpy().copy(),
        loss_curve=np.asarray(curve, dtype=np.float64),
        train_mae_db=train_mae, initial_mae_db=initial, iterations=cfg.iterations,
        wall_time_s=time.time() - t0, resumed_at=start, extra=extra)


def mae_db(pred_db: np.ndarray, meas_db: np.ndarray) -> float:
    """Mean absolute error in dB over finite entries."""
    d = np.abs(np.asarray(pred_db) - np.asarray(meas_db))
    return float(np.mean(d[np.isfinite(d)])) if np.isfinite(d).any() else math.nan
