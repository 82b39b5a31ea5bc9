"""The trainable Gaussians of stage `geom`, their activations and a small Adam that survives densification.

Raw parameters (all [N, ...] torch tensors):
- means [N, 3] m (world);
- log_scales [N, 3] log m, along the local axes (the third starts along the normal);
- rotations [N, 4] quaternion wxyz (normalised by the tracer);
- opacity_logits [N]: opacity = sigmoid;
- color_logits [N, 3]: RGB = sigmoid (view-independent appearance);
- normals_raw [N, 3]: normal = normalize (a learnable attribute, docs/physics.md section 2, not the shortest axis).

The optimiser keeps its moments as tensors with the same first dimension, so densification and
pruning only index or extend them, and a checkpoint is a flat dict of tensors.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

PARAM_NAMES = ("means", "log_scales", "rotations", "opacity_logits", "color_logits", "normals_raw")


def logit(p: torch.Tensor | float) -> torch.Tensor:
    p = torch.as_tensor(p, dtype=torch.float32).clamp(1e-6, 1 - 1e-6)
    return torch.log(p / (1 - p))


class GaussianModel:
    """Raw parameters plus Adam moments (beta1 0.9, beta2 0.999, eps 1e-15).

    lrs: learning rate per parameter name (the means' rate is scheduled by the trainer).
    """

    def __init__(self, params: dict[str, torch.Tensor], lrs: dict[str, float]):
        missing = set(PARAM_NAMES) - set(params)
        if missing:
            raise ValueError(f"missing parameters: {sorted(missing)}")
        self.params = {k: params[k].detach().clone().requires_grad_(True) for k in PARAM_NAMES}
        self.lrs = dict(lrs)
        self.exp_avg = {k: torch.zeros_like(v) for k, v in self.params.items()}
        self.exp_avg_sq = {k: torch.zeros_like(v) for k, v in self.params.items()}
        self.step_count = 0

    # ------------------------------------------------------------------ activations
    @property
    def num(self) -> int:
        return int(self.params["means"].shape[0])

    def opacities(self) -> torch.Tensor:
        """[N] in (0, 1)."""
        return torch.sigmoid(self.params["opacity_logits"])

    def colors(self) -> torch.Tensor:
        """[N, 3] RGB in (0, 1)."""
        return torch.sigmoid(self.params["color_logits"])

    def normals(self) -> torch.Tensor:
        """[N, 3] unit normals."""
        return F.normalize(self.params["normals_raw"], dim=-1, eps=1e-12)

    # ------------------------------------------------------------------ optimiser
    def zero_grad(self) -> None:
        for p in self.params.values():
            p.grad = None

    @torch.no_grad()
    def step(self, lr_scale: dict[str, float] | None = None) -> None:
        """One Adam step on every parameter with a gradient."""
        self.step_count += 1
        b1, b2, eps = 0.9, 0.999, 1e-15
        c1, c2 = 1 - b1**self.step_count, 1 - b2**self.step_count
        for name, p in self.params.items():
            if p.grad is None:
                continue
            lr = self.lrs[name] * (lr_scale or {}).get(name, 1.0)
            if lr == 0:
                continue
            g = p.grad
            self.exp_avg[name].mul_(b1).add_(g, alpha=1 - b1)
            self.exp_avg_sq[name].mul_(b2).addcmul_(g, g, value=1 - b2)
            denom = (self.exp_avg_sq[name] / c2).sqrt_().add_(eps)
            p.addcdiv_(self.exp_avg[name], denom, value=-lr / c1)

    # ------------------------------------------------------------------ topology changes
    @torch.no_grad()
    def keep(self, mask: torch.Tensor) -> None:
        """Keep only the Gaussians where mask [N] (bool) is true (parameters and moments)."""
        for store in (self.exp_avg, self.exp_avg_sq):
            for k in store:
                store[k] = store[k][mask].contiguous()
        for k in PARAM_NAMES:
            self.params[k] = self.params[k].detach()[mask].contiguous().requires_grad_(True)

    @torch.no_grad()
    def append(self, new: dict[str, torch.Tensor]) -> None:
        """Add Gaussians (raw parameters [M, ...] per name) with zero optimiser moments."""
        for k in PARAM_NAMES:
            self.params[k] = torch.cat([self.params[k].detach(), new[k].to(self.params[k])]).requires_grad_(True)
            for store in (self.exp_avg, self.exp_avg_sq):
                store[k] = torch.cat([store[k], torch.zeros_like(new[k]).to(store[k])])

    # ------------------------------------------------------------------ checkpoints
    def state(self) -> dict[str, torch.Tensor | int]:
        out: dict = {"step_count": self.step_count}
        for k in PARAM_NAMES:
            out[f"param.{k}"] = self.params[k].detach().clone()
            out[f"exp_avg.{k}"] = self.exp_avg[k].clone()
            out[f"exp_avg_sq.{k}"] = self.exp_avg_sq[k].clone()
        return out

    def load_state(self, state: dict) -> None:
        self.step_count = int(state["step_count"])
        for k in PARAM_NAMES:
            self.params[k] = state[f"param.{k}"].clone().requires_grad_(True)
            self.exp_avg[k] = state[f"exp_avg.{k}"].clone()
            self.exp_avg_sq[k] = state[f"exp_avg_sq.{k}"].clone()

    def to(self, device) -> "GaussianModel":
        for k in PARAM_NAMES:
            self.params[k] = self.params[k].detach().to(device).requires_grad_(True)
            self.exp_avg[k] = self.exp_avg[k].to(device)
            self.exp_avg_sq[k] = self.exp_avg_sq[k].to(device)
        return self


def rotation_matrices(quats: torch.Tensor) -> torch.Tensor:
    """Quaternions [N, 4] wxyz (any non-zero norm) -> rotation matrices [N, 3, 3] (local-to-world)."""
    q = F.normalize(quats, dim=-1)
    w, x, y, z = q.unbind(-1)
    return torch.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ], dim=-1).reshape(-1, 3, 3)


def sample_inside(means: torch.Tensor, log_scales: torch.Tensor, rotations: torch.Tensor, generator: torch.Generator,
                  spread: float = 1.0) -> torch.Tensor:
    """One point [N, 3] drawn from each Gaussian N(mu, (spread s)^2 along the local axes)."""
    eps = torch.randn(means.shape, generator=generator, dtype=means.dtype, device="cpu").to(means.device)
    local = eps * torch.exp(log_scales) * spread
    return means + torch.einsum("nij,nj->ni", rotation_matrices(rotations), local)


def as_numpy_fields(model: GaussianModel) -> dict[str, np.ndarray]:
    """Scene-artifact fields (`gaussians/...`, float64) of the current Gaussians."""
    with torch.no_grad():
        q = F.normalize(model.params["rotations"], dim=-1)
        q = q * torch.where(q[:, :1] < 0, -1.0, 1.0)
        return {
            "gaussians/means": model.params["means"].double().cpu().numpy(),
            "gaussians/log_scales": model.params["log_scales"].double().cpu().numpy(),
            "gaussians/rotations": q.double().cpu().numpy(),
            "gaussians/opacities": model.opacities().double().cpu().numpy(),
            "gaussians/colors": model.colors().double().cpu().numpy(),
            "gaussians/normals": model.normals().double().cpu().numpy(),
        }
