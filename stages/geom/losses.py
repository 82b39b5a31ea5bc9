"""Image and geometry losses of stage `geom` (docs/physics.md section 3).

All maps are torch tensors laid out [H, W, C] (or [H, W]) in image order: row v (down), column u
(right), OpenCV camera axes. Colours are linear in [0, 1]; depths are metres along the ray.

L = l1 L1 + lssim (1 - SSIM) + ln |N - N~| + lu (D_sq - D^2) / d_ref^2 + lsn |grad N| exp(-|grad C_gt|)

- N~ (pseudo-normal): the normal of the surface the rendered depth map describes, from the cross
  product of its finite differences (local planarity), facing the camera.
- D_sq - D^2 (depth uncertainty): the spread of the depths that make up a pixel; divided by the
  squared reference distance d_ref (typical camera distance) so the weight is scale-free.
- |grad N| exp(-|grad C_gt|): normal smoothness, relaxed where the photo has an edge.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F

SSIM_C1 = 0.01**2
SSIM_C2 = 0.03**2


def gaussian_window(size: int = 11, sigma: float = 1.5, dtype=torch.float32, device=None) -> torch.Tensor:
    """Normalised 2D Gaussian window [size, size] (sums to 1)."""
    x = torch.arange(size, dtype=torch.float64) - (size - 1) / 2
    g = torch.exp(-(x**2) / (2 * sigma**2))
    g = g / g.sum()
    return torch.outer(g, g).to(dtype=dtype, device=device)


def ssim_map(img: torch.Tensor, ref: torch.Tensor, window: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Structural similarity per window position and channel.

    img, ref: [H, W, C] in [0, 1] (H, W >= window). Local means, variances and covariance are
    weighted with a Gaussian window (valid positions only, no padding):
    SSIM = (2 mx my + C1)(2 sxy + C2) / ((mx^2 + my^2 + C1)(sx^2 + sy^2 + C2)), C1 = 0.01^2, C2 = 0.03^2.
    Returns [H - window + 1, W - window + 1, C].
    """
    if img.shape != ref.shape or img.dim() != 3:
        raise ValueError(f"ssim expects two [H, W, C] images of one shape, got {tuple(img.shape)} and {tuple(ref.shape)}")
    c = img.shape[2]
    w = gaussian_window(window, sigma, img.dtype, img.device)[None, None].expand(c, 1, window, window)
    x = img.permute(2, 0, 1)[None]
    y = ref.permute(2, 0, 1)[None]

    def blur(t):
        return F.conv2d(t, w, groups=c)

    mx, my = blur(x), blur(y)
    sxx = blur(x * x) - mx * mx
    syy = blur(y * y) - my * my
    sxy = blur(x * y) - mx * my
    num = (2 * mx * my + SSIM_C1) * (2 * sxy + SSIM_C2)
    den = (mx * mx + my * my + SSIM_C1) * (sxx + syy + SSIM_C2)
    return (num / den)[0].permute(1, 2, 0)


def ssim(img: torch.Tensor, ref: torch.Tensor, window: int = 11, sigma: float = 1.5) -> torch.Tensor:
    """Mean SSIM of two [H, W, C] images (a scalar tensor, 1 for identical images)."""
    return ssim_map(img, ref, window, sigma).mean()


def psnr(img: torch.Tensor, ref: torch.Tensor) -> float:
    """Peak signal-to-noise ratio in dB for images in [0, 1]."""
    mse = float(((img - ref) ** 2).mean())
    return float("inf") if mse == 0 else -10.0 * math.log10(mse)


def pseudo_normals(depth: torch.Tensor, dirs: torch.Tensor, origin: torch.Tensor) -> torch.Tensor:
    """Normals of the surface described by a depth map, facing the camera.

    depth: [H, W] distance along each ray [m]; dirs: [H, W, 3] unit ray directions (world);
    origin: [3] camera centre [m]. The points P = o + depth * d are differenced over the two
    neighbours in each image direction (central differences), N~ = normalize(dP/dv x dP/du),
    flipped to face the camera. Returns [H - 2, W - 2, 3] for the interior pixels.
    """
    pts = origin + depth[..., None] * dirs
    du = pts[1:-1, 2:] - pts[1:-1, :-2]
    dv = pts[2:, 1:-1] - pts[:-2, 1:-1]
    n = torch.cross(dv, du, dim=-1)  # (down x right) = towards the camera for OpenCV axes
    n = F.normalize(n, dim=-1, eps=1e-12)
    facing = (n * dirs[1:-1, 1:-1]).sum(-1, keepdim=True)
    return torch.where(facing > 0, -n, n)


def interior(t: torch.Tensor) -> torch.Tensor:
    """The [H - 2, W - 2, ...] interior of a map (matches pseudo_normals)."""
    return t[1:-1, 1:-1]


def surface_mask(acc: torch.Tensor, threshold: float = 0.5) -> torch.Tensor:
    """Interior pixels [H - 2, W - 2] where the pixel and its 4 neighbours are opaque (acc > threshold)."""
    m = acc.detach() > threshold
    return m[1:-1, 1:-1] & m[:-2, 1:-1] & m[2:, 1:-1] & m[1:-1, :-2] & m[1:-1, 2:]


def depth_normal_loss(normal: torch.Tensor, pseudo: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Mean over masked interior pixels of |N - N~|_2 (normal: the rendered [H, W, 3] map)."""
    diff = torch.linalg.vector_norm(interior(normal) - pseudo, dim=-1)
    return _masked_mean(diff, mask)


def depth_uncertainty_loss(depth: torch.Tensor, depth_sq: torch.Tensor, ref_distance_m: float) -> torch.Tensor:
    """Mean of (D_sq - D^2) / d_ref^2 over all pixels ([H, W] maps; >= 0 up to round-off)."""
    return ((depth_sq - depth * depth) / (ref_distance_m**2)).clamp_min(0).mean()


def normal_smoothness_loss(normal: torch.Tensor, image_gt: torch.Tensor) -> torch.Tensor:
    """Edge-aware normal smoothness: mean of |grad N|_1 exp(-|grad C_gt|) over both image directions.

    normal: [H, W, 3] rendered normals; image_gt: [H, W, 3] the photo (its gradient is the mean
    absolute difference over channels).
    """
    gx = (normal[:, 1:] - normal[:, :-1]).abs().sum(-1)
    gy = (normal[1:] - normal[:-1]).abs().sum(-1)
    wx = torch.exp(-(image_gt[:, 1:] - image_gt[:, :-1]).abs().mean(-1))
    wy = torch.exp(-(image_gt[1:] - image_gt[:-1]).abs().mean(-1))
    return 0.5 * ((gx * wx).mean() + (gy * wy).mean())


def _masked_mean(values: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    count = mask.sum()
    if int(count) == 0:
        return values.sum() * 0.0
    return (values * mask).sum() / count
