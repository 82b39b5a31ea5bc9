"""A NeRF2-style neural radio field for RSSI and monostatic RCS prediction (baseline; our own implementation from the
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
- receiver inside the scene box (RSSI): N_dir rays from the receiver on a Fibonacci sphere, S
  samples per ray from the receiver to the exit of the scene box (midpoints, or stratified: one
  uniform sample per bin, in training).
- receiver outside the box (monostatic RCS: the radar, several metres from a small object): a
  sphere of directions would send almost every ray past the object, so the N_dir rays are cast in
  the cone toward the box centre whose half-angle covers the box's bounding sphere (`cone_dirs`:
  a Fibonacci spiral, uniform in solid angle over that spherical cap; the whole sphere when the
  receiver is inside the bounding sphere). The S samples lie between the ray's box entry and exit
  (`ray_box`); rays that miss the box contribute nothing (zero weight).
- per ray: T_i = exp(-sum_{j<i} sigma_j dt), w_i = T_i (1 - exp(-sigma_i dt)), ray = sum_i w_i s_i.
- received signal = sum over rays (complex); power in dB = 10 log10(|sum|^2) + learnable offset.

Training (`train_nerf2`): MSE in dB on the training links, Adam, mini-batches of links, learning
rate decayed by 10x over the run (by epochs or the wall-clock budget, whichever ends first).

Monostatic RCS: transmitter = receiver = the radar, so the Tx input is the radar position (the
field is again entangled with the source). Positions far outside the scene box would make the Tx
encoding alias, so when a transmitter lies outside the box the Tx input is normalised over a cube
that holds the box and every transmitter (`source_box`); with every transmitter inside (RSSI) it
is the scene box, as before.

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

from .fields import decay_lr, encode, fibonacci_sphere
from .fields import mlp as _mlp


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





class Nerf2Field(nn.Module):
    """Neural radio field: attenuation network sigma(x), feature(x) and a radiance network
    s(x, direction, Tx) in C (as 2 reals). `bounds` [2, 3] m is the scene box (lo, hi): it
    normalises positions and bounds the rays. `tx_bounds` [2, 3] m normalises the Tx input
    (default: `bounds`; see `source_box`). `offset_db` is the learnable power offset."""

    def __init__(self, bounds, settings: Nerf2Settings | None = None, tx_bounds=None):
        super().__init__()
        s = settings or Nerf2Settings()
        self.settings = s
        b = torch.as_tensor(np.asarray(bounds, dtype=np.float32))
        self.register_buffer("lo", b[0].clone())
        self.register_buffer("hi", b[1].clone())
        tb = b if tx_bounds is None else torch.as_tensor(np.asarray(tx_bounds, dtype=np.float32))
        self.register_buffer("tx_lo", tb[0].clone())   # box normalising the Tx input (default: the scene box)
        self.register_buffer("tx_hi", tb[1].clone())
        self.register_buffer("dirs", fibonacci_sphere(s.n_dirs).float())
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

    def normalise_tx(self, tx: torch.Tensor) -> torch.Tensor:
        """Tx positions [.., 3] m -> [-1, 1]^3 over the Tx box (the scene box unless given)."""
        return 2 * (tx - self.tx_lo) / (self.tx_hi - self.tx_lo) - 1

    def radiance(self, feat: torch.Tensor, dirs: torch.Tensor, tx: torch.Tensor) -> torch.Tensor:
        """Signal emitted toward the receiver. feat [B, N, S, F], dirs [N, 3] or [B, N, 3] (unit,
        receiver -> point), tx [B, 3] m -> [B, N, S, 2] (real, imag)."""
        s = self.settings
        hd = self.rad_dir(encode(dirs, s.n_freqs_dir))
        hd = hd[None] if hd.dim() == 2 else hd              # [1 or B, N, W]
        h = (self.rad_feat(feat)
             + hd[:, :, None, :]
             + self.rad_tx(encode(self.normalise_tx(tx), s.n_freqs_tx))[:, None, None, :])
        return self.rad(torch.relu(h))


def source_box(bounds, tx) -> np.ndarray | None:
    """Box [2, 3] m normalising the Tx input: None (= the scene box `bounds`) when every Tx of
    tx [L, 3] lies inside it (RSSI), else the cube around the union of the box and all Tx
    positions, padded by 5 % (monostatic RCS: the radar is far outside the object's box). A cube
    keeps the encoding isotropic when the Tx all lie in one plane."""
    b = np.asarray(bounds, dtype=np.float64)
    tx = np.asarray(tx, dtype=np.float64).reshape(-1, 3)
    if tx.size == 0 or bool(((tx >= b[0]) & (tx <= b[1])).all()):
        return None
    lo, hi = np.minimum(b[0], tx.min(0)), np.maximum(b[1], tx.max(0))
    c, h = 0.5 * (lo + hi), 0.5 * float((hi - lo).max()) * 1.05
    return np.stack([c - h, c + h])


def _ray_exit(rx: torch.Tensor, dirs: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor) -> torch.Tensor:
    """Distance [B, N] m from rx [B, 3] (inside the box) along dirs [N, 3] to the box's boundary."""
    d = dirs[None]                                           # [1, N, 3]
    safe = torch.where(d.abs() < 1e-9, torch.full_like(d, 1e-9), d)
    t_hi = (hi - rx)[:, None, :] / safe
    t_lo = (lo - rx)[:, None, :] / safe
    t = torch.where(d > 0, t_hi, t_lo).clamp(min=0)
    return t.min(-1).values.clamp(min=0.05)


def ray_box(origin: torch.Tensor, dirs: torch.Tensor, lo: torch.Tensor,
            hi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Slab test: origin [B, 3] m, dirs [B, N, 3] unit -> (t_near [B, N], t_far [B, N], hit [B, N]).

    [t_near, t_far] is the part of the ray (t >= 0) inside the box; t_near = 0 for an origin
    inside. hit is False where the ray misses the box (then t_near = t_far = 0)."""
    safe = torch.where(dirs.abs() < 1e-12, torch.full_like(dirs, 1e-12), dirs)
    t1 = (lo - origin)[:, None, :] / safe
    t2 = (hi - origin)[:, None, :] / safe
    t_near = torch.minimum(t1, t2).max(-1).values.clamp(min=0)
    t_far = torch.maximum(t1, t2).min(-1).values
    hit = t_far > t_near
    zero = torch.zeros_like(t_near)
    return torch.where(hit, t_near, zero), torch.where(hit, t_far, zero), hit


def cone_dirs(origin: torch.Tensor, centre: torch.Tensor, radius: float, n: int) -> torch.Tensor:
    """[B, n, 3] unit directions from origin [B, 3] m, uniform in solid angle (a Fibonacci spiral
    on the spherical cap) over the cone toward centre [3] whose half-angle asin(radius / distance)
    covers the sphere (centre, radius); the whole sphere for an origin inside that sphere. The
    cone's frame turns with the origin (its second axis is horizontal, axis x z), so it varies
    smoothly as a radar moves around the object."""
    i = torch.arange(n, dtype=origin.dtype, device=origin.device) + 0.5
    axis = centre - origin                                   # [B, 3]
    dist = axis.norm(dim=-1, keepdim=True).clamp(min=1e-12)
    w = axis / dist
    cos_a = torch.sqrt(torch.clamp(1 - (radius / dist) ** 2, min=0))    # [B, 1]; 0 -> hemisphere
    cos_a = torch.where(dist > radius, cos_a, torch.full_like(cos_a, -1.0))
    ct = 1 - (1 - cos_a) * i / n                             # [B, n] uniform in cos(theta) on the cap
    st = torch.sqrt(torch.clamp(1 - ct * ct, min=0))
    phi = math.pi * (3 - math.sqrt(5)) * i
    ref = torch.zeros_like(w)
    ref[:, 2] = 1.0
    near_z = w[:, 2].abs() > 0.99
    ref[near_z] = torch.tensor([1.0, 0.0, 0.0], dtype=w.dtype, device=w.device)
    u = torch.linalg.cross(w, ref)
    u = u / u.norm(dim=-1, keepdim=True)
    v = torch.linalg.cross(w, u)
    return (ct[..., None] * w[:, None] + (st * torch.cos(phi))[..., None] * u[:, None]
            + (st * torch.sin(phi))[..., None] * v[:, None])


def ray_segments(field: Nerf2Field, rx: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Rays of the receivers rx [B, 3] m: (dirs [B, N, 3], t_near [B, N], t_far [B, N]) in m.

    Inside the scene box: the Fibonacci sphere, from the receiver to the box exit (at least 5 cm).
    Outside: `cone_dirs` toward the box (its bounding sphere), from box entry to exit; a ray that
    misses the box has t_near = t_far = 0 (no samples' weight)."""
    lo, hi = field.lo, field.hi
    rx = rx.to(lo.dtype)
    n = field.dirs.shape[0]
    inside = ((rx >= lo) & (rx <= hi)).all(-1)               # [B]
    dirs = field.dirs[None].expand(rx.shape[0], n, 3)
    rx_c = torch.maximum(torch.minimum(rx, hi), lo)
    t_far = _ray_exit(rx_c, field.dirs, lo, hi)              # [B, N]
    t_near = torch.zeros_like(t_far)
    if not bool(inside.all()):
        out = ~inside
        centre, radius = 0.5 * (lo + hi), 0.5 * float((hi - lo).norm())
        d_out = cone_dirs(rx[out], centre, radius, n)
        tn, tf, _ = ray_box(rx[out], d_out, lo, hi)
        dirs = dirs.clone()
        dirs[out] = d_out
        t_near, t_far = t_near.clone(), t_far.clone()
        t_near[out], t_far[out] = tn, tf
    return dirs, t_near, t_far


def render_links(field: Nerf2Field, tx: torch.Tensor, rx: torch.Tensor, stratified: bool = False,
                 generator: torch.Generator | None = None) -> torch.Tensor:
    """Received power [B] dB for links tx [B, 3] m -> rx [B, 3] m (rays cast from rx, see
    `ray_segments`; stratified: one random sample per depth bin, else bin midpoints)."""
    s = field.settings
    tx, rx = tx.to(field.lo.dtype), rx.to(field.lo.dtype)
    dirs, t_near, t_far = ray_segments(field, rx)            # [B, N, 3], [B, N], [B, N]
    dt = (t_far - t_near) / s.n_samples                      # [B, N]; 0 for rays that miss the box
    if stratified:
        u = torch.rand(rx.shape[0], dirs.shape[1], s.n_samples, generator=generator, device=rx.device,
                       dtype=rx.dtype)
    else:
        u = torch.full((1, 1, s.n_samples), 0.5, device=rx.device, dtype=rx.dtype)
    t = t_near[..., None] + (torch.arange(s.n_samples, device=rx.device) + u) * dt[..., None]   # [B, N, S]
    pts = rx[:, None, None, :] + t[..., None] * dirs[:, :, None, :]               # [B, N, S, 3]
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

    bounds [2, 3] m: the scene box (default: the links' positions' box, padded by 0.5 m). Receivers
    outside it (monostatic RCS: tx = rx = the radar) cast their rays in the cone toward the box
    (`ray_segments`), and the Tx input is normalised over `source_box(bounds, tx)`.
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
    field = Nerf2Field(bounds, s, tx_bounds=source_box(bounds, tx_t.numpy()))
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
            decay_lr(opt, base_lrs, s.lr_decay, step, total_steps, elapsed, budget)
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
