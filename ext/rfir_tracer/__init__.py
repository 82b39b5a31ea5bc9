"""rfir_tracer: the Gaussian ray tracer of rfir (C++/OpenMP on the CPU, CUDA on a GPU).

Rays are traced through 3D Gaussians with a BVH and composited front to back as in
docs/physics.md section 2. Typical use::

    scene = rfir_tracer.GaussianScene(means, log_scales, rotations, opacities, normals)
    out = rfir_tracer.trace(scene, origins, directions, features=colours)
    out.features, out.depth, out.normal, out.transmittance   # differentiable
    vis = rfir_tracer.transmittance_to_points(scene, tx_pos, ids, opacities=rf_opacities)

``rfir_tracer.reference`` holds the brute-force float64 torch oracle used by the tests.
"""
from ._ext import backend_info
from .result import HitLists, TraceResult
from .scene import GaussianScene
from .trace import trace, trace_transmittance, transmittance_to_points

__all__ = ["GaussianScene", "HitLists", "TraceResult", "backend_info", "trace", "trace_transmittance",
           "transmittance_to_points"]
