"""Render a view of the Gaussians through the ext/ tracer (rfir_tracer): colour, depth, normals.

Rays leave the camera centre through every pixel centre (unit directions, so depths are metres
along the ray). Normals are two-sided: for each view every Gaussian's normal is flipped to face
the camera before compositing, so the rendered normal map always faces the viewer.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch

import rfir_tracer as rt

from .model import GaussianModel


@dataclass
class Render:
    """Maps of one view ([H, W] or [H, W, 3]).

    color: composited RGB over the background; depth, depth_sq: sum w t, sum w t^2 (m, m^2);
    normal: sum w n (facing the camera, not normalised); acc: 1 - transmittance (coverage).
    """

    color: torch.Tensor
    depth: torch.Tensor
    depth_sq: torch.Tensor
    normal: torch.Tensor
    acc: torch.Tensor

    def expected_depth(self, min_acc: float = 1e-3) -> torch.Tensor:
        """Depth normalised by coverage [H, W] (m): the mean depth of what the pixel sees."""
        return self.depth / self.acc.clamp_min(min_acc)


def make_scene(model: GaussianModel, alpha_min: float) -> rt.GaussianScene:
    """A tracer scene sharing the model's geometry tensors (refits itself after optimiser steps)."""
    p = model.params
    return rt.GaussianScene(p["means"], p["log_scales"], p["rotations"], model.opacities().detach(),
                            model.normals().detach(), alpha_min=alpha_min)


def render_view(scene: rt.GaussianScene, model: GaussianModel, origin: torch.Tensor, dirs: torch.Tensor,
                background: torch.Tensor, *, t_stop: float = 1e-4) -> Render:
    """Render rays (origin [3], dirs [H, W, 3]) with the model's current (differentiable) attributes."""
    p = model.params
    if scene.means is not p["means"] or scene.num_gaussians != model.num:
        scene.update(means=p["means"], log_scales=p["log_scales"], rotations=p["rotations"], rebuild=True)
    normals = model.normals()
    with torch.no_grad():
        facing = torch.where(((origin - p["means"]) * normals).sum(-1, keepdim=True) < 0, -1.0, 1.0)
    scene.normals = normals * facing
    out = rt.trace(scene, origin, dirs, features=model.colors(), opacities=model.opacities(), t_stop=t_stop)
    acc = 1.0 - out.transmittance
    color = out.features + out.transmittance[..., None] * background
    return Render(color, out.depth, out.depth_sq, out.normal, acc)
