"""Differentiable tracing through a GaussianScene (torch.autograd wrapper of rfir_tracer._C).

Gradients flow to means, log-scales, rotations, opacities, normals and features; not to ray
origins, directions or the t limits.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch.autograd.function import once_differentiable

from . import _checks
from ._ext import native
from .result import HitLists, TraceResult
from .scene import GaussianScene


@dataclass
class _Static:
    """Non-differentiable inputs of one traced batch."""

    nodes: torch.Tensor
    prim_order: torch.Tensor
    origins: torch.Tensor
    dirs: torch.Tensor
    t_min: torch.Tensor
    t_max: torch.Tensor
    exclude: torch.Tensor | None
    params: object
    want_hits: bool


def _scene_tensors(means, log_scales, rotations, opacities, normals, features, st: _Static):
    C = native()
    s = C.SceneTensors()
    s.means, s.log_scales, s.rotations = means, log_scales, rotations
    s.opacities, s.normals, s.features = opacities, normals, features
    s.nodes, s.prim_order = st.nodes, st.prim_order
    r = C.RayTensors()
    r.origins, r.dirs, r.t_min, r.t_max = st.origins, st.dirs, st.t_min, st.t_max
    if st.exclude is not None:
        r.exclude = st.exclude
    return s, r


class _TraceFn(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means, log_scales, rotations, opacities, normals, features, st: _Static):
        s, r = _scene_tensors(means, log_scales, rotations, opacities, normals, features, st)
        outs = native().forward(s, r, st.params, st.want_hits)
        feat, depth, depth_sq, normal, trans, count, off, ids, ht, hg, evals = outs
        ctx.mark_non_differentiable(count, off, ids, ht, hg, evals)
        ctx.save_for_backward(means, log_scales, rotations, opacities, normals, features,
                              feat, depth, depth_sq, normal, trans, off, ids, ht)
        ctx.st = st
        return feat, depth, depth_sq, normal, trans, count, off, ids, ht, hg, evals

    @staticmethod
    @once_differentiable
    def backward(ctx, g_feat, g_depth, g_depth_sq, g_normal, g_trans, *_unused):
        (means, log_scales, rotations, opacities, normals, features,
         feat, depth, depth_sq, normal, trans, off, ids, ht) = ctx.saved_tensors
        st = ctx.st
        outs = [feat, depth, depth_sq, normal, trans]
        grads = [torch.zeros_like(o) if g is None else g.contiguous()
                 for g, o in zip((g_feat, g_depth, g_depth_sq, g_normal, g_trans), outs)]
        s, r = _scene_tensors(means, log_scales, rotations, opacities, normals, features, st)
        gm, gl, gr, go, gn, gf = native().backward(s, r, st.params, outs, grads, off, ids, ht)
        if normals.shape[0] == 0:
            gn = None
        return gm, gl, gr, go, gn, gf, None


def _params(alpha_min: float, t_stop: float):
    p = native().TraceParams()
    p.alpha_min, p.t_stop, p.alpha_max = float(alpha_min), float(t_stop), _checks.ALPHA_MAX
    p.kappa2 = _checks.kappa2(alpha_min)
    return p


def _checked(scene, origins, directions, opacities, t_min, t_max, alpha_min, t_stop):
    """Validated (alpha_min, prepared rays (o, d, t_min, t_max, batch shape), opacities) of one call."""
    if not isinstance(scene, GaussianScene):
        raise TypeError(f"scene must be a GaussianScene, got {type(scene).__name__}")
    alpha_min = scene.bvh_alpha_min if alpha_min is None else float(alpha_min)
    _checks.check_params(alpha_min, t_stop)
    rays = _checks.prepare_rays(origins, directions, t_min, t_max, scene.dtype, scene.device)
    opac = scene.opacities if opacities is None else opacities
    _checks.check_opacities(opac, scene.num_gaussians)
    return alpha_min, rays, opac


def _exclude_ids(exclude, batch, device) -> torch.Tensor:
    """[R] int32 Gaussian id each ray ignores, broadcast over the rays' batch shape."""
    return torch.broadcast_to(torch.as_tensor(exclude, device=device), batch).reshape(-1).to(torch.int32).contiguous()


def trace(scene: GaussianScene, origins: torch.Tensor, directions: torch.Tensor, *,
          features: torch.Tensor | None = None, opacities: torch.Tensor | None = None,
          t_min=0.0, t_max=math.inf, alpha_min: float | None = None, t_stop: float = 1e-4,
          exclude: torch.Tensor | None = None, return_hits: bool = False) -> TraceResult:
    """Trace rays ``x(t) = o + t d`` through the scene and composite front to back (docs/physics.md section 2).

    Args:
        scene: the Gaussians and their BVH.
        origins: [3] or [..., 3] ray origins, metres (broadcast to the directions).
        directions: [..., 3] non-zero directions; t is in units of |d| (metres when unit).
        features: [N, K] per-Gaussian features to composite (colour, ...); None for K = 0.
        opacities: [N] in [0, 1] overriding scene.opacities (e.g. RF opacities).
        t_min, t_max: float or [...] limits; hits need t_min < t* < t_max.
        alpha_min: ignore hits with alpha below this (default: the scene's, 1/255).
        t_stop: stop once transmittance < t_stop.
        exclude: optional [...] int Gaussian id each ray ignores (-1: none).
        return_hits: also return the CSR hit lists (result.hits).

    Returns:
        TraceResult with features [..., K], depth, depth_sq, transmittance [...], normal
        [..., 3], hit_count [...] int32, hits (or None).
    """
    alpha_min, (o, d, tmin, tmax, batch), opac = _checked(scene, origins, directions, opacities, t_min, t_max,
                                                          alpha_min, t_stop)
    n, dtype, device = scene.num_gaussians, scene.dtype, scene.device
    if features is None:
        features = torch.zeros(n, 0, dtype=dtype, device=device)
    if not isinstance(features, torch.Tensor) or features.dim() != 2:
        raise ValueError("features must be a tensor of shape [N, K]")
    _checks.check_matrix(features, "features", features.shape[1], n)
    _checks.check_finite(features, "features")
    normals = scene.normals
    if normals is None:
        normals = torch.zeros(0, 3, dtype=dtype, device=device)
    _checks.check_finite(normals, "normals")
    for t, name in ((opac, "opacities"), (features, "features"), (normals, "normals")):
        if t.device != device:
            raise ValueError(f"{name} is on {t.device} but the scene is on {device}")
    ex = None if exclude is None else _exclude_ids(exclude, batch, device)
    scene.ensure_bvh(alpha_min)
    tensors = [scene.means, scene.log_scales, scene.rotations, opac, normals, features]
    tensors = [t.to(dtype).contiguous() for t in tensors]
    needs_grad = torch.is_grad_enabled() and any(t.requires_grad for t in tensors)
    st = _Static(scene.nodes, scene.prim_order, o, d, tmin, tmax, ex, _params(alpha_min, t_stop),
                 bool(return_hits or needs_grad))
    feat, depth, depth_sq, normal, trans, count, off, ids, ht, hg, ev = _TraceFn.apply(*tensors, st)
    hits = HitLists(off, ids, ht, hg) if return_hits else None
    return TraceResult(features=feat.reshape(batch + (feat.shape[1],)), depth=depth.reshape(batch),
                       depth_sq=depth_sq.reshape(batch), normal=normal.reshape(batch + (3,)),
                       transmittance=trans.reshape(batch), hit_count=count.reshape(batch), hits=hits,
                       evaluations=ev.reshape(batch))


def trace_transmittance(scene: GaussianScene, origins: torch.Tensor, directions: torch.Tensor, *,
                        opacities: torch.Tensor | None = None, t_min=0.0, t_max=math.inf,
                        alpha_min: float | None = None, t_stop: float = 1e-4,
                        exclude: torch.Tensor | None = None) -> torch.Tensor:
    """Transmittance [...] of each ray, without gradients, features or hit lists: the fast path.

    Same rays, acceptance rules and arguments as ``trace``; the hits are multiplied in BVH
    traversal order in one pass, so the result equals ``trace(...).transmittance`` to rounding
    when t_stop = 0, and both are below t_stop when the ray is stopped early. On CUDA it runs
    ``trace`` (the CPU kernel is the one that needs the shortcut).
    """
    if isinstance(scene, GaussianScene) and scene.device.type != "cpu":
        with torch.no_grad():
            return trace(scene, origins, directions, opacities=opacities, t_min=t_min, t_max=t_max,
                         alpha_min=alpha_min, t_stop=t_stop, exclude=exclude).transmittance
    alpha_min, (o, d, tmin, tmax, batch), opac = _checked(scene, origins, directions, opacities, t_min, t_max,
                                                          alpha_min, t_stop)
    n, dtype, device = scene.num_gaussians, scene.dtype, scene.device
    s = native().SceneTensors()
    s.means, s.log_scales, s.rotations = (t.detach().to(dtype).contiguous()
                                          for t in (scene.means, scene.log_scales, scene.rotations))
    s.opacities = opac.detach().to(device, dtype).contiguous()
    s.normals = torch.zeros(0, 3, dtype=dtype, device=device)
    s.features = torch.zeros(n, 0, dtype=dtype, device=device)
    scene.ensure_bvh(alpha_min)
    s.nodes, s.prim_order = scene.nodes, scene.prim_order
    r = native().RayTensors()
    r.origins, r.dirs, r.t_min, r.t_max = o, d, tmin, tmax
    if exclude is not None:
        r.exclude = _exclude_ids(exclude, batch, device)
    trans, _evals = native().transmittance(s, r, _params(alpha_min, t_stop))
    return trans.reshape(batch)


def transmittance_to_points(scene: GaussianScene, origins: torch.Tensor, gaussian_ids: torch.Tensor,
                            *, opacities: torch.Tensor | None = None, alpha_min: float | None = None,
                            t_stop: float = 1e-4, return_hits: bool = False) -> TraceResult:
    """Visibility V of each target Gaussian from a point (docs/physics.md section 4.1).

    V_m = prod over Gaussians hit on the segment from origins[m] to means[gaussian_ids[m]]
    (0 < t* < 1, the target itself excluded) of (1 - alpha), with the same compositing, alpha
    clamp, alpha_min and t_stop rules as ``trace``. Differentiable w.r.t. opacities (pass RF
    opacities here) and the Gaussians' geometry (not the segment's end points).

    Args:
        origins: [3] or [M, 3] points (e.g. the transmitter), metres.
        gaussian_ids: [M] int target Gaussians.
        opacities: [N] in [0, 1] overriding scene.opacities.

    Returns:
        TraceResult over the M segments: ``transmittance`` [M] is V; ``depth`` is in segment
        units (0..1); ``hits`` when return_hits.
    """
    ids = torch.as_tensor(gaussian_ids, device=scene.device)
    if ids.dim() != 1 or ids.dtype.is_floating_point:
        raise ValueError("gaussian_ids must be a 1-D integer tensor")
    n = scene.num_gaussians
    if ids.numel() and (int(ids.min()) < 0 or int(ids.max()) >= n):
        raise ValueError(f"gaussian_ids must lie in [0, {n}), got [{int(ids.min())}, {int(ids.max())}]")
    ids = ids.long()
    m = ids.shape[0]
    if not isinstance(origins, torch.Tensor):
        raise ValueError("origins must be a tensor of shape [3] or [M, 3]")
    o = torch.broadcast_to(origins.detach().to(scene.device, scene.dtype), (m, 3))
    d = scene.means.detach()[ids] - o
    degenerate = d.abs().sum(dim=1) == 0  # point at the target's centre: nothing in between
    d = torch.where(degenerate[:, None], torch.ones_like(d), d)
    t_max = torch.where(degenerate, torch.zeros_like(d[:, 0]), torch.ones_like(d[:, 0]))
    return trace(scene, o, d, opacities=opacities, t_min=0.0, t_max=t_max, alpha_min=alpha_min,
                 t_stop=t_stop, exclude=ids, return_hits=return_hits)
