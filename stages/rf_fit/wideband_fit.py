"""Two-step wideband fit: (1) base materials and s_tx(f) over the band, (2) the modulation network
on top (docs/physics.md section 7). Loss: dB MSE of path gain over the training links and a random subset
of `freqs_per_step` frequencies per step (the full [M, G, K] problem does not fit in memory).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
import torch

from rfir_cli.errors import ConfigError
from rfir_cli.progress import NullProgress

from .wideband import PairCache, WidebandModel, subset_links

WB_KEYS = ("enabled", "base_iterations", "net_iterations", "freqs_per_step", "links_per_step", "knots", "net_lr", "net_base_lr",
           "embed_dim", "hidden", "layers", "fourier", "pair_floor", "save_base", "auto_model", "fit_freqs")
BAND_MODELS = ("physical", "free")


@dataclass
class WidebandConfig:
    """The [rf_fit.wideband] table. lr / s_tx_lr / init values come from [rf_fit]."""

    enabled: bool = False
    base_iterations: int = 400
    net_iterations: int = 400
    freqs_per_step: int = 16
    links_per_step: int = 0
    knots: int = 17
    net_lr: float = 0.003
    net_base_lr: float = 0.0
    embed_dim: int = 8
    hidden: int = 64
    layers: int = 3
    fourier: int = 4
    pair_floor: float = 1e-8
    save_base: bool = False
    auto_model: str = "physical"   # what rf_fit.model = "auto" fits on a band (configs/rf_fit.toml)
    fit_freqs: int = 64            # the physical model's fitting frequencies, evenly spaced over the band

    def __post_init__(self):
        if self.auto_model not in BAND_MODELS:
            raise ConfigError(f"rf_fit.wideband.auto_model = {self.auto_model!r}: expected one of "
                              f"{', '.join(BAND_MODELS)}")
        if not isinstance(self.fit_freqs, int) or isinstance(self.fit_freqs, bool) or self.fit_freqs < 2:
            raise ConfigError(f"rf_fit.wideband.fit_freqs = {self.fit_freqs!r}: expected a whole number >= 2")
        if self.freqs_per_step < 1 or self.knots < 1 or self.layers < 1 or self.hidden < 1:
            raise ConfigError("rf_fit.wideband: freqs_per_step, knots, layers and hidden must be >= 1")
        if self.base_iterations < 0 or self.net_iterations < 0:
            raise ConfigError("rf_fit.wideband: base_iterations and net_iterations must be >= 0")

    @classmethod
    def from_table(cls, table: dict | None) -> WidebandConfig:
        return cls(**{k: table[k] for k in WB_KEYS if k in (table or {})})

    def net_kwargs(self) -> dict:
        return {"embed_dim": self.embed_dim, "hidden": self.hidden, "layers": self.layers, "fourier": self.fourier}


@dataclass
class WidebandFitResult:
    """Loss curves per step, MAEs in dB over all training links x all frequencies, times in s."""

    base_curve: np.ndarray
    net_curve: np.ndarray
    base_train_mae_db: float
    train_mae_db: float
    initial_mae_db: float
    base_time_s: float
    net_time_s: float
    base_state: dict = field(default_factory=dict)


def full_mae_db(model: WidebandModel, pairs: PairCache, freqs_hz: torch.Tensor, target: torch.Tensor,
                chunk: int = 16, max_freqs: int = 64) -> float:
    """Mean |pred - target| dB over every link and up to `max_freqs` evenly spaced frequencies."""
    cols = torch.unique(torch.linspace(0, freqs_hz.shape[0] - 1, min(max_freqs, freqs_hz.shape[0])).round().long())
    freqs_hz, target = freqs_hz[cols], target[:, cols]
    with torch.no_grad():
        tot = 0.0
        for a in range(0, freqs_hz.shape[0], chunk):
            tot += float((model.predict_db(pairs, freqs_hz[a:a + chunk]) - target[:, a:a + chunk]).abs().sum())
    return tot / target.numel()


def init_system_gain(model: WidebandModel, pairs: PairCache, freqs_hz: torch.Tensor, target: torch.Tensor) -> None:
    """Knot values so that the median prediction matches the median measurement at the nearest
    measured frequency of each knot."""
    with torch.no_grad():
        kf = model.s_tx.knot_freqs_hz()
        cols = torch.argmin((freqs_hz[None] - kf[:, None]).abs(), 1)
        model.s_tx.knots_db.zero_()
        pred = model.predict_db(pairs, freqs_hz[cols])
        model.s_tx.knots_db.copy_(torch.nanmedian(target[:, cols] - pred, dim=0).values)


def _run(model, pairs, freqs_hz, target, opt, iterations, k_step, m_step, gen, progress, label) -> list:
    curve = []
    n = freqs_hz.shape[0]
    with progress.task(label, total=iterations) as bar:
        for it in range(iterations):
            cols = torch.randperm(n, generator=gen)[:k_step]
            if 0 < m_step < pairs.num_links:
                rows = torch.randperm(pairs.num_links, generator=gen)[:m_step].sort().values
                batch, tgt = subset_links(pairs, rows), target[rows][:, cols]
            else:
                batch, tgt = pairs, target[:, cols]
            opt.zero_grad()
            loss = ((model.predict_db(batch, freqs_hz[cols]) - tgt) ** 2).mean()
            if not torch.isfinite(loss):
                raise FloatingPointError(f"{label}: loss became {float(loss)} at iteration {it}")
            loss.backward()
            opt.step()
            curve.append(float(loss.detach()))
            bar.advance(1)
    return curve


def fit_wideband(model: WidebandModel, pairs: PairCache, freqs_hz, target_db, cfg: WidebandConfig, *, lr: float,
                 s_tx_lr: float, learn=("opacity", "roughness", "gamma_abs", "gamma_phase", "s_tx"), seed: int = 0,
                 progress=None) -> WidebandFitResult:
    """Fit `model` to target_db [M, K] (path gain dB at freqs_hz [K]) on the pairs' links.

    Each step: `freqs_per_step` random frequencies x `links_per_step` random links (0: all).
    Step 1: base attributes (`learn`) with Adam (lr; s_tx knots s_tx_lr), network off.
    Step 2: network on; network and s_tx knots learned (net_lr, s_tx_lr); base attributes at
    net_base_lr (0: frozen). Returns curves, MAEs (all training links x all frequencies)."""
    progress = progress or NullProgress()
    gen = torch.Generator().manual_seed(seed)
    freqs_hz = torch.as_tensor(np.asarray(freqs_hz), dtype=torch.float64)
    target = torch.as_tensor(np.asarray(target_db), dtype=torch.float64)
    k_step = min(cfg.freqs_per_step, freqs_hz.shape[0])
    b = model.base
    table = {"opacity": b.theta_a, "roughness": b.theta_r, "gamma_abs": b.theta_g, "gamma_phase": b.theta_phi}
    base_params = [table[n] for n in learn if n in table]
    learn_s_tx = "s_tx" in learn

    model.use_network = False
    init_system_gain(model, pairs, freqs_hz, target)
    initial = full_mae_db(model, pairs, freqs_hz, target)
    t0 = time.time()
    groups = [{"params": base_params, "lr": lr}] + ([{"params": [model.s_tx.knots_db], "lr": s_tx_lr}]
                                                   if learn_s_tx else [])
    base_curve = _run(model, pairs, freqs_hz, target, torch.optim.Adam(groups), cfg.base_iterations, k_step,
                      cfg.links_per_step, gen,
                      progress, "wideband base")
    base_time = time.time() - t0
    base_mae = full_mae_db(model, pairs, freqs_hz, target)
    base_state = model.flat_state()

    net_curve, net_time = [], 0.0
    if cfg.net_iterations > 0:
        model.use_network = True
        for p in base_params:
            p.requires_grad_(cfg.net_base_lr > 0)
        t1 = time.time()
        groups = [{"params": list(model.net.parameters()), "lr": cfg.net_lr}]
        if learn_s_tx:
            groups.append({"params": [model.s_tx.knots_db], "lr": s_tx_lr * 0.1})
        if cfg.net_base_lr > 0 and base_params:
            groups.append({"params": base_params, "lr": cfg.net_base_lr})
        net_curve = _run(model, pairs, freqs_hz, target, torch.optim.Adam(groups), cfg.net_iterations, k_step,
                         cfg.links_per_step, gen,
                         progress, "wideband network")
        net_time = time.time() - t1
    final = full_mae_db(model, pairs, freqs_hz, target)
    return WidebandFitResult(np.asarray(base_curve), np.asarray(net_curve), base_mae, final, initial, base_time,
                             net_time, base_state)
