"""A NeRF2-style neural radio field for RSSI prediction (baseline; our own implementation from the
description in Zhao et al., "NeRF2: Neural Radio-Frequency Radiance Fields", MobiCom 2023).

Model
- attenuation network: x [.., 3] m -> (sigma(x) >= 0 [1/m], feature [.., F]), input = positional
  encoding of x normalised to the scene box ([-1, 1]^3), `n_freqs_pos` frequencies.
- radiance network: (feature, encoded ray direction, encoded Tx position) -> complex signal that
  the point x emits toward the receiver, as (real, imag). The Tx position is an input: the field
  is entangled with the source, which is the point of this baseline (every new transmitter needs
  the network to generalise in Tx space).
  The first radiance layer acts on the concatenation [feature, dir, tx]; it is computed as three
  linear maps added together (identical maths), so the direction and Tx parts are evaluated once
  per direction / per link instead of once per sample.

Rendering at a receiver (`render_links`)
- N_dir rays from the receiver on a Fibonacci sphere, S samples per ray from the receiver to the
  exit of the scene box (midpoints, or stratified: one uniform sample per bin, in training).
- per ray: T_i = exp(-sum_{j<i} sigma_j dt), w_i = T_i (1 - exp(-sigma_i dt)), ray = sum_i w_i s_i.
- received signal = sum over rays (complex); power in dB = 10 log10(|sum|^2) + learnable offset.

Training (`train_nerf2`): MSE in dB on the training links, Adam, mini-batches of links, learning
rate decayed by 10x over the run (by epochs or the wall-clock budget, whichever ends first).

Simplifications relative to the paper: real (not complex) attenuation, so no phase rotation
along the ray and no explicit path-delay term; one frequency; power only (no channel phase in the
loss); small CPU-sized MLPs, few rays and samples.
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np
import torch
from torch import nn


@dataclass
class Nerf2Settings:
    """Model, rendering and training settings (units: m, s, dB)."""

    n_freqs_pos: int = 6          # positional-encoding frequencies of the sample point
    n_freqs_dir: int = 4          # ... of the ray direction
    n_freqs_tx: int = 4           # ... of the transmitter position
    width: int = 64               # hidden width of both MLPs
    att_layers: int = 3           # hidden layers of the attenuation network
    rad_layers: int = 2           # hidden layers of the radiance network
    feat_dim: int = 32            # feature passed from the attenuation to the radiance network
    n_dirs: int = 64              # rays per receiver (Fibonacci sphere)
    n_samples: int = 24           # samples per ray
    batch_links: int = 128        # links per mini-batch
    epochs: int = 20
    lr: float = 2e-3
    lr_offset: float = 5e-2       # learning rate of the dB offset
    lr_decay: float = 0.1         # final lr / initial lr
    minutes: float | None = None  # wall-clock training budget (None: no budget)
    eval_batch: int = 256
    seed: int = 0


def fibonacci_sphere(n: int) -> torch.Tensor:
    """[n, 3] unit vectors spread evenly over the sphere."""
    i = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1 - 2 * i / n
    r = torch.sqrt(torch.clamp(1 - z * z, min=0))
    phi = math.pi * (3 - math.sqrt(5)) * i
    return torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], 1).float()


def encode(x: torch.Tensor, n_freqs: int) -> torch.Tensor:
    """Positional encoding [.., D] -> [.., D (1 + 2 n_freqs)]: x, sin(2^k pi x), cos(2^k pi x)."""
    freqs = (2.0 ** torch.arange(n_freqs, dtype=x.dtype, device=x.device)) * math.pi
    xf = (x[..., None, :] * freqs[:, None]).flatten(-2)
    return torch.cat([x, torch.sin(xf), torch.cos(xf)], -1)


def _mlp(n_in: int, width: int, layers: int, n_out: int) -> nn.Sequential:
    mods: list[nn.Module] = []
    d = n_in
    for _ in range(layers):
        mods += [nn.Linear(d, width), nn.ReLU()]
        d = width
    mods.append(nn.Linear(d, n_out))
    return nn.Sequential(*mods)


class Nerf2Field(nn.Module):
    """Neural radio field: attenuation network sigma(x), feature(x) and a radiance network
    s(x, direction, Tx) in C (as 2 reals). `bounds` [2, 3] m is the scene box (lo, hi): it
    normalises positions and ends the rays. `offset_db` is the learnable power offset."""

    def __init__(self, bounds, settings: Nerf2Settings | None = None):
        super().__init__()
        s = settings or Nerf2Settings()
        self.settings = s
        b = torch.as_tensor(np.asarray(bounds, dtype=np.float32))
        self.register_buffer("lo", b[0].clone())
        self.register_buffer("hi", b[1].clone())
        self.register_buffer("dirs", fibonacci_sphere(s.n_dirs))
        self.att = _mlp(3 * (1 + 2 * s.n_freqs_pos), s.width, s.att_layers, 1 + s.feat_dim)
        with torch.no_grad():       # start nearly transparent: sigma ~ softplus(-3) ~ 0.05 / m
            self.att[-1].bias[0] = -3.0
        w = s.width
        self.rad_feat = nn.Linear(s.feat_dim, w)
        self.rad_dir = nn.Linear(3 * (1 + 2 * s.n_freqs_dir), w, bias=False)
        self.rad_tx = nn.Linear(3 * (1 + 2 * s.n_freqs_tx), w, bias=False)
        self.rad = _mlp(w, w, s.rad_layers - 1, 2) if s.rad_layers > 1 else nn.Linear(w, 2)
        self.offset_db = nn.Parameter(torch.zeros(()))
        self.float()   # float32 whatever torch's default dtype is (another module may have changed it)

    def normalise(self, x: torch.Tensor) -> torch.Tensor:
        """Positions [.., 3] m -> [-1, 1]^3 over the scene box."""
        return 2 * (x - self.lo) / (self.hi - self.lo) - 1

    def attenuation(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """x [.., 3] m -> sigma [..] 1/m (>= 0), feature [.., feat_dim]."""
        h = self.att(encode(self.normalise(x), self.settings.n_freqs_pos))
        return nn.functional.softplus(h[..., 0]), h[..., 1:]

    def radiance(self, feat: torch.Tensor, dirs: torch.Tensor, tx: torch.Tensor) -> torch.Tensor:
        """Signal emitted toward the receiver. feat [B, N, S, F], dirs [N, 3] (unit, receiver ->
        point), tx [B, 3] m -> [B, N, S, 2] (real, imag)."""
        s = self.settings
        h = (self.rad_feat(feat)
             + self.rad_dir(encode(dirs, s.n_freqs_dir))[None, :, None, :]
             + self.rad_tx(encode(self.normalise(tx), s.n_freqs_tx))[:, None, None, :])
        return self.rad(torch.relu(h))


def _ray_exit(rx: torch.Tensor, dirs: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
    """Distance [B, N] m from rx [B, 3] (inside the box) along dirs [N, 3] to the box's boundary."""
    d = dirs[None]                                           # [1, N, 3]
    safe = torch.where(d.abs() < 1e-9, torch.full_like(d, 1e-9), d)
    t_hi = (hi - rx)[:, None, :] / safe
    t_lo = (lo - rx)[:, None, :] / safe
    t = torch.where(d > 0, t_hi, t_lo).clamp(min=0)
    return t.min(-1).values.clamp(min=0.05)


def render_links(field: Nerf2Field, tx: torch.Tensor, rx: torch.Tensor, stratified: bool = False,
                 generator: torch.Generator | None = None) -> torch.Tensor:
    """Received power [B] dB for links tx [B, 3] m -> rx [B, 3] m (rays cast from rx; stratified:
    one random sample per depth bin, else bin midpoints)."""
    s = field.settings
    dirs = field.dirs                                        # [N, 3]
    rx_c = torch.maximum(torch.minimum(rx, field.hi), field.lo)
    t_far = _ray_exit(rx_c, dirs, field.lo, field.hi)        # [B, N]
    dt = t_far / s.n_samples                                 # [B, N]
    if stratified:
        u = torch.rand(rx.shape[0], dirs.shape[0], s.n_samples, generator=generator, device=rx.device)
    else:
        u = torch.full((1, 1, s.n_samples), 0.5, device=rx.device)
    t = (torch.arange(s.n_samples, device=rx.device) + u) * dt[..., None]          # [B, N, S]
    pts = rx_c[:, None, None, :] + t[..., None] * dirs[None, :, None, :]          # [B, N, S, 3]
    sigma, feat = field.attenuation(pts)
    tau = sigma * dt[..., None]                              # optical depth per sample
    trans = torch.exp(-(torch.cumsum(tau, -1) - tau))        # T_i, exclusive cumulative sum
    w = trans * (1 - torch.exp(-tau))                        # [B, N, S]
    sig = field.radiance(feat, dirs, tx)                     # [B, N, S, 2]
    total = (w[..., None] * sig).sum((1, 2))                 # [B, 2] complex sum over rays
    power = (total * total).sum(-1)
    return 10 * torch.log10(power + 1e-20) + field.offset_db


def predict_nerf2(field: Nerf2Field, tx, rx, batch: int = 256) -> np.ndarray:
    """Power [L] dB for links tx [L, 3] m, rx [L, 3] m (numpy or torch), deterministic rendering."""
    tx = torch.as_tensor(np.asarray(tx, dtype=np.float32))
    rx = torch.as_tensor(np.asarray(rx, dtype=np.float32))
    out = []
    was = field.training
    field.eval()
    with torch.no_grad():
        for i in range(0, len(tx), batch):
            out.append(render_links(field, tx[i:i + batch], rx[i:i + batch]))
    field.train(was)
    return torch.cat(out).double().numpy() if out else np.zeros(0)


def train_nerf2(tx, rx, y_db, train_idx, settings: Nerf2Settings | None = None,
                progress: Callable[[dict], None] | None = None, bounds=None,
                eval_idx=None) -> tuple[Nerf2Field, dict]:
    """Fit a field on the links `train_idx` of tx [L, 3] m, rx [L, 3] m, y_db [L] dB.

    bounds [2, 3] m: the scene box (default: the links' positions' box, padded by 0.5 m).
    eval_idx: optional links scored (MAE dB) after every epoch, for the history only.
    progress(info) is called after every epoch with {epoch, loss, mae_train_db, lr, elapsed_s, ...}.
    Returns (field, history) with history = {epochs: [...], wall_time_s, stopped_by, steps}.
    """
    s = settings or Nerf2Settings()
    torch.manual_seed(s.seed)
    gen = torch.Generator().manual_seed(s.seed)
    tx_t = torch.as_tensor(np.asarray(tx, dtype=np.float32))
    rx_t = torch.as_tensor(np.asarray(rx, dtype=np.float32))
    y_t = torch.as_tensor(np.asarray(y_db, dtype=np.float32))
    train_idx = np.asarray(train_idx)
    if bounds is None:
        allp = torch.cat([tx_t, rx_t])
        bounds = torch.stack([allp.min(0).values - 0.5, allp.max(0).values + 0.5]).numpy()
    field = Nerf2Field(bounds, s)
    tr = torch.as_tensor(train_idx, dtype=torch.long)
    with torch.no_grad():           # start at the training mean
        probe = tr[torch.randperm(len(tr), generator=gen)[:min(len(tr), s.eval_batch)]]
        raw = render_links(field, tx_t[probe], rx_t[probe])
        field.offset_db.fill_(float(y_t[tr].mean() - raw.mean()))
    net_params = [p for n, p in field.named_parameters() if n != "offset_db"]
    opt = torch.optim.Adam([{"params": net_params, "lr": s.lr},
                            {"params": [field.offset_db], "lr": s.lr_offset}])
    base_lrs = [s.lr, s.lr_offset]
    t0 = time.perf_counter()
    budget = None if s.minutes is None else 60.0 * s.minutes
    steps_per_epoch = max(1, math.ceil(len(tr) / s.batch_links))
    total_steps = s.epochs * steps_per_epoch
    hist: dict = {"epochs": [], "stopped_by": "epochs"}
    step = 0
    for epoch in range(s.epochs):
        perm = tr[torch.randperm(len(tr), generator=gen)]
        losses, abs_err, stop = [], [], False
        for i in range(0, len(perm), s.batch_links):
            elapsed = time.perf_counter() - t0
            if budget is not None and elapsed > budget:
                stop = True
                break
            frac = step / total_steps
            if budget is not None:
                frac = max(frac, elapsed / budget)
            for g, lr0 in zip(opt.param_groups, base_lrs):
                g["lr"] = lr0 * s.lr_decay ** min(frac, 1.0)
            b = perm[i:i + s.batch_links]
            pred = render_links(field, tx_t[b], rx_t[b], stratified=True, generator=gen)
            err = pred - y_t[b]
            loss = (err * err).mean()
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            step += 1
            losses.append(loss.item())
            abs_err.append(err.detach().abs())
        if not losses:
            hist["stopped_by"] = "time"
            break
        info = {"epoch": epoch + 1, "loss": float(np.mean(losses)),
                "mae_train_db": float(torch.cat(abs_err).mean()),  # running, stratified, during the epoch
                "lr": opt.param_groups[0]["lr"], "elapsed_s": time.perf_counter() - t0,
                "offset_db": field.offset_db.item(), "steps": step, "partial": stop}
        if eval_idx is not None and len(eval_idx):
            ev = np.asarray(eval_idx)
            p = predict_nerf2(field, tx_t[ev].numpy(), rx_t[ev].numpy(), s.eval_batch)
            info["mae_eval_db"] = float(np.mean(np.abs(p - y_t[ev].numpy())))
        hist["epochs"].append(info)
        if progress is not None:
            progress(info)
        if stop:
            hist["stopped_by"] = "time"
            break
    hist["wall_time_s"] = time.perf_counter() - t0
    hist["steps"] = step
    hist["settings"] = asdict(s)
    return field, hist
