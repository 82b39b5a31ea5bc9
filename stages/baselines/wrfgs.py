"""A WRF-GS-style Gaussian radio field (baseline; our own implementation from the idea of Wen et al.,
"Neural Representation for Wireless Radiation Field Reconstruction: A 3D Gaussian Splatting
Approach", 2024; nothing copied from any other project).

Model (`WrfgsField`)
- G frozen 3D Gaussians (means [G, 3] m, log-scales [G, 3] log m, rotations [G, 4] wxyz) taken
  from an rfir `scene` artifact; each carries a learnable feature f_g [G, F] and a learnable
  attenuation (opacity) logit o_g [G].
- The signal Gaussian g radiates toward the receiver along a ray of direction d (unit, receiver ->
  Gaussian) for a transmitter at tx is complex, s_g = MLP(f_g, enc(mean_g), enc(tx), enc(d)) as
  (real, imag). The transmitter position is an input: the field is ENTANGLED with the source (every
  new transmitter position needs the MLP to generalise in tx space; a moved object needs new data).
  The first layer acts on the concatenation and is computed as three linear maps added together
  (identical maths): per Gaussian, per link, per ray.
  enc() is the NeRF positional encoding; Gaussian means are normalised to the Gaussians' box, tx
  positions to the cube around all link end points.

Rendering a receiver (`render_links`)
- N rays from the receiver: a Fibonacci sphere (`rays="sphere"`, RSSI: the receiver sits inside
  the scene) or a Fibonacci spherical cap aimed at the Gaussians' centre that just covers their
  bounding sphere (`rays="cone"`, RCS: the radar is far from a small object, a full sphere of 128
  rays would hardly hit it; this is the analogue of the paper's receiver "camera" looking at the
  scene).
- The geometry is frozen, so every receiver is traced ONCE through rfir_tracer (BVH, opacity 1,
  all hits with G >= alpha_min kept, front to back) and its hit lists (ray, Gaussian g, response
  G in (0, 1], t m) are stored (`ReceiverHits`). Each training step then composites in pure torch:
  alpha_i = min(sigmoid(o_g) G_i, 0.99), T_i = prod_{j<i on the ray} (1 - alpha_j),
  ray signal = sum_i T_i alpha_i s_{g_i}(tx, d), received = sum over rays (complex),
  power dB = 10 log10 |received|^2 + a learnable offset (dB).
  Gradients reach o_g (through alpha and T), f_g, the MLP and the offset.

Training (`train_wrfgs`): Adam on the MSE in dB over mini-batches of links; learning rates decay by
`lr_decay` over the run (by epochs or the wall-clock budget, whichever ends first); the offset
starts at the training mean. With validation links (`val_idx`, taken from the training rows by the
caller, never from the test rows) the parameters of the epoch with the best validation MAE are kept
(early stopping; the model overfits small training sets badly otherwise).

Shapes/units: tx, rx [L, 3] m (world frame of the scene), y_db [L] dB (path gain), predictions [L]
dB. Everything trains in float32 (the hit tables are traced in float64 and stored in float32; the
transmittance's cumulative sum runs in float64), whatever torch's default dtype is.

Simplifications relative to the paper: ray tracing of a fixed set of rays instead of splatting the
Gaussians onto the receiver's angular image (so small Gaussians between rays are missed; the
aliasing is fixed per receiver and the MLP absorbs it); geometry (means, covariances) frozen to
the scene artifact instead of optimised with densification / pruning; the attenuation is a
per-Gaussian learnable scalar (not predicted from the transmitter); one frequency; power only (no
channel phase in the loss, no explicit propagation phase); small CPU-sized MLP.
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

ALPHA_MAX = 0.99   # the tracer's alpha clamp (docs/physics.md section 2)




@dataclass
class WrfgsSettings:
    """Model, rendering and training settings (units: m, s, dB)."""

    rays: str = "sphere"          # "sphere" (receiver inside the scene) or "cone" (aimed at the Gaussians)
    n_dirs: int = 128             # rays per receiver
    cone_margin: float = 1.05     # cone half-angle covers margin x the Gaussians' bounding sphere
    alpha_min: float = 0.02       # hits with G below this are dropped (opacity <= 1; speed)
    max_gaussians: int | None = None   # random subset of the scene's Gaussians (None: all)
    feat_dim: int = 16            # learnable feature per Gaussian
    n_freqs_pos: int = 4          # positional encoding of the Gaussian's mean
    n_freqs_dir: int = 4          # ... of the ray direction
    n_freqs_tx: int = 4           # ... of the transmitter position
    width: int = 64               # hidden width of the signal MLP
    layers: int = 2               # hidden layers of the signal MLP (the first is the split linear map)
    opacity_init: float = 0.5     # initial sigmoid(o_g)
    batch_links: int = 64
    epochs: int = 40
    lr: float = 2e-3              # MLP
    lr_gauss: float = 1e-2        # per-Gaussian features and opacity logits
    lr_offset: float = 5e-2       # the dB offset
    lr_decay: float = 0.1         # final lr / initial lr
    minutes: float | None = None  # wall-clock training budget (None: no budget)
    eval_batch: int = 128
    seed: int = 0



def cap_directions(n: int, axis: torch.Tensor, half_angle: torch.Tensor) -> torch.Tensor:
    """[U, n, 3] unit vectors spread (Fibonacci) over spherical caps around axis [U, 3] (unit) with
    half-angles [U] rad (pi: the whole sphere)."""
    i = torch.arange(n, dtype=torch.float64) + 0.5
    cmin = torch.cos(half_angle.double())[:, None]                 # [U, 1]
    z = 1 - (1 - cmin) * i / n                                      # [U, n] cos of the polar angle
    r = torch.sqrt(torch.clamp(1 - z * z, min=0))
    phi = (math.pi * (3 - math.sqrt(5)) * i)[None]
    local = torch.stack([r * torch.cos(phi), r * torch.sin(phi), z], -1)   # around +z
    a = axis.double() / axis.double().norm(dim=-1, keepdim=True).clamp(min=1e-12)
    helper = torch.where(a[:, 2:3].abs() < 0.9, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64),
                         torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64))
    e1 = torch.linalg.cross(helper, a)
    e1 = e1 / e1.norm(dim=-1, keepdim=True)
    e2 = torch.linalg.cross(a, e1)
    basis = torch.stack([e1, e2, a], 1)                             # [U, 3 (local axes), 3]
    return torch.einsum("unk,ukc->unc", local, basis)


@dataclass
class ReceiverHits:
    """Hit lists of U receivers, N rays each, in CSR form over receivers (front to back per ray).

    origins [U, 3] m, dirs [U, N, 3] unit (float32), offsets [U + 1] int64 (receiver u owns hits
    offsets[u]:offsets[u + 1]); per hit: ray [H] int64 (direction index 0..N-1 within its
    receiver), gaussian [H] int64, response [H] float32 G in (0, 1], t [H] float32 m. Hits are
    sorted by (receiver, ray, t).
    """

    origins: torch.Tensor
    dirs: torch.Tensor
    offsets: torch.Tensor
    ray: torch.Tensor
    gaussian: torch.Tensor
    response: torch.Tensor
    t: torch.Tensor

    @property
    def num_hits(self) -> int:
        return int(self.gaussian.shape[0])


class WrfgsField(nn.Module):
    """Frozen Gaussians with learnable features f_g, opacity logits o_g and a signal MLP
    s(f_g, mean_g, tx, direction) in C (as 2 reals); `offset_db` is the learnable power offset.

    geometry: (means [G, 3], log_scales [G, 3], rotations [G, 4]) m / log m / wxyz.
    tx_box: (centre [3], half-size scalar) m normalising transmitter positions.
    """

    def __init__(self, means, log_scales, rotations, tx_box, settings: WrfgsSettings | None = None):
        super().__init__()
        s = settings or WrfgsSettings()
        self.settings = s
        f64 = lambda x: torch.as_tensor(np.asarray(x, dtype=np.float64))  # noqa: E731
        self.register_buffer("means64", f64(means).clone())
        self.register_buffer("log_scales64", f64(log_scales).clone())
        self.register_buffer("rotations64", f64(rotations).clone())
        m = self.means64
        lo, hi = m.min(0).values, m.max(0).values
        self.register_buffer("g_centre", 0.5 * (lo + hi))
        self.register_buffer("g_half", (0.5 * (hi - lo)).clamp(min=1e-3))
        radius = (m - self.g_centre).norm(dim=-1) + 3 * torch.exp(self.log_scales64).max(-1).values
        self.register_buffer("g_radius", radius.max() if len(m) else torch.tensor(1.0, dtype=torch.float64))
        c, h = tx_box
        self.register_buffer("tx_centre", f64(c).reshape(3).clone())
        self.register_buffer("tx_half", f64(max(float(h), 1e-3)).reshape(()).clone())
        n = m.shape[0]
        w = s.width
        self.feature = nn.Parameter(0.1 * torch.randn(n, s.feat_dim, dtype=torch.float32))
        p0 = min(max(s.opacity_init, 1e-4), 1 - 1e-4)
        self.opacity_logit = nn.Parameter(torch.full((n,), math.log(p0 / (1 - p0)), dtype=torch.float32))
        self.lin_g = nn.Linear(s.feat_dim + 3 * (1 + 2 * s.n_freqs_pos), w)
        self.lin_tx = nn.Linear(3 * (1 + 2 * s.n_freqs_tx), w, bias=False)
        self.lin_dir = nn.Linear(3 * (1 + 2 * s.n_freqs_dir), w, bias=False)
        self.head = _mlp(w, w, s.layers - 1, 2) if s.layers > 1 else nn.Linear(w, 2)
        self.offset_db = nn.Parameter(torch.zeros((), dtype=torch.float32))
        self.float()   # float32 modules whatever torch's default dtype is
        self._scene = None

    # ------------------------------------------------------------------ encodings and signal
    def gaussian_code(self) -> torch.Tensor:
        """[G, W] first-layer term of every Gaussian (feature + encoded normalised mean)."""
        pos = ((self.means64 - self.g_centre) / self.g_half).float()
        return self.lin_g(torch.cat([self.feature, encode(pos, self.settings.n_freqs_pos)], -1))

    def tx_code(self, tx: torch.Tensor) -> torch.Tensor:
        """tx [B, 3] m -> [B, W]."""
        x = ((tx.double() - self.tx_centre) / self.tx_half).float()
        return self.lin_tx(encode(x, self.settings.n_freqs_tx))

    def dir_code(self, dirs: torch.Tensor) -> torch.Tensor:
        """dirs [..., 3] unit -> [..., W]."""
        return self.lin_dir(encode(dirs.float(), self.settings.n_freqs_dir))

    def opacity(self) -> torch.Tensor:
        """[G] attenuation sigmoid(o_g) in (0, 1)."""
        return torch.sigmoid(self.opacity_logit)

    # ------------------------------------------------------------------ tracing (geometry frozen)
    def tracer_scene(self):
        if self._scene is None:
            import rfir_tracer

            self._scene = rfir_tracer.GaussianScene(self.means64.contiguous(), self.log_scales64.contiguous(),
                                                    self.rotations64.contiguous())
        return self._scene

    def ray_directions(self, origins: torch.Tensor) -> torch.Tensor:
        """[U, N, 3] ray directions (float64) of receivers at origins [U, 3] m."""
        s = self.settings
        u = origins.shape[0]
        if s.rays == "sphere":
            return fibonacci_sphere(s.n_dirs)[None].expand(u, -1, -1).contiguous()
        if s.rays != "cone":
            raise ValueError(f"rays must be 'sphere' or 'cone', got {s.rays!r}")
        axis = self.g_centre[None] - origins.double()
        dist = axis.norm(dim=-1)
        ratio = (s.cone_margin * self.g_radius / dist.clamp(min=1e-9)).clamp(max=1.0)
        half = torch.where(ratio >= 1.0, torch.full_like(ratio, math.pi), torch.asin(ratio))
        axis = torch.where(dist[:, None] > 1e-9, axis, torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64))
        return cap_directions(s.n_dirs, axis, half)

    def trace_receivers(self, origins, chunk: int = 200_000) -> ReceiverHits:
        """Trace N rays from each receiver origins [U, 3] m once (opacity 1, all hits kept)."""
        import rfir_tracer

        o = torch.as_tensor(np.asarray(origins, dtype=np.float64)).reshape(-1, 3)
        dirs = self.ray_directions(o)                                     # [U, N, 3]
        n = dirs.shape[1]
        ro = o[:, None, :].expand(-1, n, -1).reshape(-1, 3).contiguous()
        rd = dirs.reshape(-1, 3).contiguous()
        scene = self.tracer_scene()
        parts = []
        with torch.no_grad():
            for a in range(0, rd.shape[0], chunk):
                b = min(rd.shape[0], a + chunk)
                res = rfir_tracer.trace(scene, ro[a:b], rd[a:b], alpha_min=self.settings.alpha_min,
                                        t_stop=0.0, return_hits=True)
                h = res.hits
                parts.append((h.ray_ids().long() + a, h.gaussian_ids.long(), h.response.float(), h.t.float()))
        glob = torch.cat([p[0] for p in parts])
        rec = glob // n
        counts = torch.bincount(rec, minlength=o.shape[0])
        offsets = torch.zeros(o.shape[0] + 1, dtype=torch.int64)
        offsets[1:] = torch.cumsum(counts, 0)
        return ReceiverHits(o.float(), dirs.float(), offsets, glob % n, torch.cat([p[1] for p in parts]),
                            torch.cat([p[2] for p in parts]), torch.cat([p[3] for p in parts]))


def _gather(hits: ReceiverHits, recv: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Hit indices [H_b] of the receivers recv [B] (in batch order) and the batch link of each."""
    start = hits.offsets[recv]
    cnt = hits.offsets[recv + 1] - start
    link = torch.repeat_interleave(torch.arange(len(recv)), cnt)
    first = torch.cumsum(cnt, 0) - cnt
    idx = start[link] + (torch.arange(int(cnt.sum())) - first[link])
    return idx, link


def composite_weights(alpha: torch.Tensor, ray_key: torch.Tensor) -> torch.Tensor:
    """Front-to-back weights w_i = T_i alpha_i [H] for hits sorted by (ray_key, t): T_i is the
    product of (1 - alpha_j) over the earlier hits of the same ray (exclusive cumulative product,
    as a float64 cumulative sum of log(1 - alpha))."""
    if alpha.numel() == 0:
        return alpha
    lg = torch.log1p(-alpha.double())
    c = torch.cumsum(lg, 0)
    excl = c - lg                                                  # sum over all earlier hits
    first = torch.ones_like(ray_key, dtype=torch.bool)
    first[1:] = ray_key[1:] != ray_key[:-1]
    pos = torch.arange(len(ray_key))
    start = torch.cummax(torch.where(first, pos, torch.zeros_like(pos)), 0).values
    trans = torch.exp(excl - excl[start])
    return (trans * alpha.double()).to(alpha.dtype)


def render_links(field: WrfgsField, hits: ReceiverHits, recv: torch.Tensor, tx: torch.Tensor,
                 return_complex: bool = False) -> torch.Tensor:
    """Received power [B] dB of links with receivers recv [B] (indices into `hits`) and
    transmitters tx [B, 3] m (or the complex sum [B, 2] without the offset when return_complex)."""
    n = hits.dirs.shape[1]
    idx, link = _gather(hits, recv)
    g = hits.gaussian[idx]
    ray_key = link * n + hits.ray[idx]
    alpha = (field.opacity()[g] * hits.response[idx]).clamp(max=ALPHA_MAX)
    w = composite_weights(alpha, ray_key)
    per_ray = field.tx_code(tx)[:, None, :] + field.dir_code(hits.dirs[recv])      # [B, N, W]
    h = field.gaussian_code()[g] + per_ray.reshape(-1, per_ray.shape[-1])[ray_key]
    sig = field.head(torch.relu(h))                                # [H_b, 2]
    total = torch.zeros(len(recv), 2, dtype=sig.dtype).index_add_(0, link, w[:, None] * sig)
    if return_complex:
        return total
    power = (total * total).sum(-1)
    return 10 * torch.log10(power + 1e-20) + field.offset_db


def _unique_receivers(rx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unique positions [U, 3], index [L] of each link's receiver); positions equal to 1e-6 m."""
    key = np.round(np.asarray(rx, dtype=np.float64) / 1e-6).astype(np.int64)
    _, first, inv = np.unique(key, axis=0, return_index=True, return_inverse=True)
    return np.asarray(rx, dtype=np.float64)[first], inv.reshape(-1)


def predict_wrfgs(field: WrfgsField, tx, rx, batch: int | None = None, hits: ReceiverHits | None = None,
                  recv=None) -> np.ndarray:
    """Power [L] dB for links tx [L, 3] m, rx [L, 3] m. The receivers are traced here unless their
    hit lists `hits` and the links' receiver indices `recv` [L] are given."""
    tx_t = torch.as_tensor(np.asarray(tx, dtype=np.float32)).reshape(-1, 3)
    if hits is None:
        uniq, inv = _unique_receivers(np.asarray(rx).reshape(-1, 3))
        hits = field.trace_receivers(uniq)
        recv = inv
    recv_t = torch.as_tensor(np.asarray(recv), dtype=torch.int64)
    batch = batch or field.settings.eval_batch
    out = []
    was = field.training
    field.eval()
    with torch.no_grad():
        for i in range(0, len(tx_t), batch):
            out.append(render_links(field, hits, recv_t[i:i + batch], tx_t[i:i + batch]))
    field.train(was)
    return torch.cat(out).double().numpy() if out else np.zeros(0)


def tx_box_of(tx, rx, pad: float = 0.25) -> tuple[np.ndarray, float]:
    """(centre [3], half-size) of the cube around all link end points, padded by `pad` m."""
    allp = np.concatenate([np.asarray(tx, np.float64).reshape(-1, 3), np.asarray(rx, np.float64).reshape(-1, 3)])
    lo, hi = allp.min(0), allp.max(0)
    return 0.5 * (lo + hi), float(0.5 * (hi - lo).max() + pad)


def subsample_geometry(means, log_scales, rotations, max_gaussians: int | None, seed: int = 0):
    """A random subset of at most max_gaussians Gaussians (None: all), as float64 numpy arrays."""
    m, ls, r = (np.asarray(x, dtype=np.float64) for x in (means, log_scales, rotations))
    if max_gaussians is None or len(m) <= max_gaussians:
        return m, ls, r
    keep = np.sort(np.random.default_rng(seed).choice(len(m), max_gaussians, replace=False))
    return m[keep], ls[keep], r[keep]


def train_wrfgs(geometry, tx, rx, y_db, train_idx, settings: WrfgsSettings | None = None,
                progress: Callable[[dict], None] | None = None, eval_idx=None,
                tx_box=None, val_idx=None) -> tuple[WrfgsField, dict]:
    """Fit a field on the links `train_idx` of tx [L, 3] m, rx [L, 3] m, y_db [L] dB.

    geometry: (means [G, 3], log_scales [G, 3], rotations [G, 4]) of the frozen Gaussians (m, log m,
    wxyz), subsampled to settings.max_gaussians. The receivers of ALL L links are traced once
    (geometry only, no labels) and kept in `field.hits` / `field.link_receiver` [L] for prediction.
    eval_idx: optional links scored (MAE dB) after every epoch, for the history only.
    val_idx: optional validation links (disjoint from train_idx), scored after every epoch; the
    parameters of the best epoch are restored at the end (hist: best_epoch, best_val_mae_db).
    progress(info) is called after every epoch with {epoch, loss, mae_train_db, lr, elapsed_s, ...}.
    Returns (field, history) with history = {epochs: [...], wall_time_s, stopped_by, steps,
    trace_time_s, num_hits, hits_per_link}.
    """
    s = settings or WrfgsSettings()
    torch.manual_seed(s.seed)
    gen = torch.Generator().manual_seed(s.seed)
    tx_np = np.asarray(tx, dtype=np.float64).reshape(-1, 3)
    rx_np = np.asarray(rx, dtype=np.float64).reshape(-1, 3)
    means, log_scales, rotations = subsample_geometry(*geometry, s.max_gaussians, s.seed)
    field = WrfgsField(means, log_scales, rotations, tx_box or tx_box_of(tx_np, rx_np), s)
    t0 = time.perf_counter()
    uniq, inv = _unique_receivers(rx_np)
    hits = field.trace_receivers(uniq)
    trace_s = time.perf_counter() - t0
    field.hits, field.link_receiver = hits, inv
    tx_t = torch.as_tensor(tx_np, dtype=torch.float32)
    y_t = torch.as_tensor(np.asarray(y_db, dtype=np.float64), dtype=torch.float32)
    recv_t = torch.as_tensor(inv, dtype=torch.int64)
    tr = torch.as_tensor(np.asarray(train_idx), dtype=torch.long)
    with torch.no_grad():           # start at the training mean
        probe = tr[torch.randperm(len(tr), generator=gen)[:min(len(tr), s.eval_batch)]]
        raw = render_links(field, hits, recv_t[probe], tx_t[probe])
        field.offset_db.fill_(float(y_t[tr].mean() - raw[torch.isfinite(raw)].mean()))
    net = [p for n, p in field.named_parameters() if n not in ("offset_db", "feature", "opacity_logit")]
    groups = [{"params": net, "lr": s.lr}, {"params": [field.feature, field.opacity_logit], "lr": s.lr_gauss},
              {"params": [field.offset_db], "lr": s.lr_offset}]
    opt = torch.optim.Adam(groups)
    base_lrs = [s.lr, s.lr_gauss, s.lr_offset]
    t1 = time.perf_counter()
    budget = None if s.minutes is None else 60.0 * s.minutes
    steps_per_epoch = max(1, math.ceil(len(tr) / s.batch_links))
    total_steps = s.epochs * steps_per_epoch
    hist: dict = {"epochs": [], "stopped_by": "epochs", "trace_time_s": trace_s, "num_receivers": int(len(uniq)),
                  "num_gaussians": int(len(means)), "num_hits": hits.num_hits,
                  "hits_per_link": float(hits.num_hits / max(1, len(uniq)))}
    step = 0
    best = None
    for epoch in range(s.epochs):
        perm = tr[torch.randperm(len(tr), generator=gen)]
        losses, abs_err, stop = [], [], False
        for i in range(0, len(perm), s.batch_links):
            elapsed = time.perf_counter() - t1
            if budget is not None and elapsed > budget:
                stop = True
                break
            decay_lr(opt, base_lrs, s.lr_decay, step, total_steps, elapsed, budget)
            b = perm[i:i + s.batch_links]
            pred = render_links(field, hits, recv_t[b], tx_t[b])
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
                "mae_train_db": float(torch.cat(abs_err).mean()),  # running, during the epoch
                "lr": opt.param_groups[0]["lr"], "elapsed_s": time.perf_counter() - t1,
                "offset_db": field.offset_db.item(), "steps": step, "partial": stop}
        if eval_idx is not None and len(eval_idx):
            ev = np.asarray(eval_idx)
            p = predict_wrfgs(field, tx_np[ev], None, s.eval_batch, hits=hits, recv=inv[ev])
            info["mae_eval_db"] = float(np.mean(np.abs(p - y_t.numpy()[ev])))
        if val_idx is not None and len(val_idx):
            vi = np.asarray(val_idx)
            p = predict_wrfgs(field, tx_np[vi], None, s.eval_batch, hits=hits, recv=inv[vi])
            info["mae_val_db"] = float(np.mean(np.abs(p - y_t.numpy()[vi])))
            if best is None or info["mae_val_db"] < best[0]:
                best = (info["mae_val_db"], epoch + 1, {k: v.detach().clone() for k, v in field.state_dict().items()})
        hist["epochs"].append(info)
        if progress is not None:
            progress(info)
        if stop:
            hist["stopped_by"] = "time"
            break
    if best is not None:
        field.load_state_dict(best[2])
        hist["best_epoch"], hist["best_val_mae_db"] = best[1], best[0]
    hist["wall_time_s"] = time.perf_counter() - t1
    hist["steps"] = step
    hist["settings"] = asdict(s)
    return field, hist
