"""Monostatic RCS of perfect conductors by the boundary-element method (bempp-cl).

Formulation: the electric field integral equation (EFIE) for the surface current J on a PEC
surface or open screen, Galerkin with lowest-order RWG basis functions and SNC (rotated RWG) test
functions, n x E_scat = -n x E_inc. The EFIE holds for open screens (plates, dihedrals), where the
combined-field equation does not; on closed bodies it fails only near interior resonances (a sphere:
ka = 2.744, 4.493, ...). One dense LU factorisation serves every aspect (one right-hand side each).

Normalisation: with a unit plane wave E_inc = p exp(i k d.r) (bempp's exp(-i w t) convention) the
far field is E_s ~ F(x) exp(i k r) / r; the monostatic co-polar RCS is sigma = 4 pi |F(x_hat).p|^2,
the textbook sigma = lim 4 pi r^2 |E_s|^2 / |E_0|^2, as in `rfir_stages.po` (far-field mode).
Mesh: edges of lambda / 10 or finer (the RWG rule of thumb); the error then is ~0.1-0.3 dB.
"""
from __future__ import annotations

import time

import numpy as np

from rfir_core.physics.polarisation import antenna_polarisation

from .mie import C0


def _bempp():
    try:
        import bempp_cl.api as bempp
    except ImportError as exc:  # the optional extra is missing
        raise ImportError("the full-wave solver needs bempp-cl: pip install 'rfir[fullwave]'") from exc
    return bempp


def bem_monostatic_rcs(vertices, faces, freq_hz: float, directions, polarization: str = "V",
                       timings: dict | None = None) -> np.ndarray:
    """Monostatic co-polar RCS sigma [m^2], shape (M,), of a PEC mesh by EFIE/RWG boundary elements.

    vertices (V,3) m and faces (F,3) int: a conforming triangle mesh (shared edges share vertices),
    closed or open; freq_hz scalar; directions (M,3): unit vectors from the object toward the radar
    (the wave travels along -direction); polarization "V" or "H" as in `rfir_stages.po`
    (`antenna_polarisation` of the beam direction -direction; transmit = receive).
    timings, if given, receives "assembly_s", "factor_s", "solve_s" (all aspects) and "dofs".
    """
    bempp = _bempp()
    from bempp_cl.api.assembly.grid_function import callable as bempp_callable
    from bempp_cl.api.operators.boundary import maxwell
    from bempp_cl.api.operators.far_field import maxwell as far_field
    from scipy.linalg import lu_factor, lu_solve

    u = np.asarray(directions, float).reshape(-1, 3)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    pol = antenna_polarisation(-u, polarization)  # (M,3)
    k = 2.0 * np.pi * float(freq_hz) / C0
    grid = bempp.Grid(np.ascontiguousarray(np.asarray(vertices, float).T),
                      np.ascontiguousarray(np.asarray(faces).T.astype(np.uint32)))
    rwg = bempp.function_space(grid, "RWG", 0)
    snc = bempp.function_space(grid, "SNC", 0)
    t0 = time.perf_counter()
    a = maxwell.electric_field(rwg, rwg, snc, k).weak_form().to_dense()
    t1 = time.perf_counter()
    lu = lu_factor(a, overwrite_a=True, check_finite=False)
    t2 = time.perf_counter()

    # right-hand sides: the SNC projections of the tangential incident field, one per aspect
    rhs = np.empty((rwg.global_dof_count, len(u)), dtype=complex)
    current = {}

    @bempp_callable(complex=True, vectorized=True)
    def n_cross_e_inc(x, n, domain_index, result):
        # x, n (3, Q): quadrature points and normals; result (3, Q) = E_inc x n (bempp's tangential trace)
        e = current["p"][:, None] * np.exp(-1j * k * (current["u"] @ x))[None, :]
        result[:] = np.cross(e, n, axis=0)

    for m in range(len(u)):
        current["u"], current["p"] = u[m], pol[m]
        rhs[:, m] = bempp.GridFunction(rwg, fun=n_cross_e_inc, dual_space=snc).projections(snc)
    coeffs = lu_solve(lu, rhs, check_finite=False)
    # far field of every solution toward its own radar: one operator for all M directions
    ff = far_field.electric_field(rwg, np.ascontiguousarray(u.T), k)
    sigma = np.empty(len(u))
    for m in range(len(u)):
        f = ff.evaluate(bempp.GridFunction(rwg, coefficients=coeffs[:, m]))[:, m]
        sigma[m] = 4.0 * np.pi * abs(f @ pol[m]) ** 2
    t3 = time.perf_counter()
    if timings is not None:
        timings.update(assembly_s=t1 - t0, factor_s=t2 - t1, solve_s=t3 - t2, dofs=int(rwg.global_dof_count),
                       aspects=int(len(u)))
    return sigma
