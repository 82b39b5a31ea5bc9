"""A 2D method-of-moments reference: the monostatic echo width of a perfectly conducting strip (zero
thickness, width w, infinite along its edges), for the edge-wave checks of docs/physics.md section 8.13.

The strip lies on x = 0, -w/2 <= y <= w/2; the radar is far away in direction s = (cos theta, sin theta):
theta is the angle from the strip's normal (0: broadside, 90: grazing, in the strip's plane). Time
convention exp(+j omega t); 2D Green's function G(r) = H0^(2)(k r) / (4 j).

- "TM" (E along the edges, the soft case): the electric-field integral equation for the axial current
  J_z, pulse basis, point matching at the cells' centres:
      j k eta sum_m J_m int_(cell m) G(y_n - y') dy' = E_z^inc(y_n).
- "TE" (H along the edges, E across them: the hard case): the electric-field integral equation for the
  transverse current J_y, written with the vector and scalar potentials so that no derivative falls on
  the kernel: triangle (rooftop) basis for J_y on the interior nodes (it vanishes at the edges, as the
  current across an edge must), so that the charge rho = -(dJ/dy) / (j omega) is constant on each cell;
  pulse testing on [y_n - h/2, y_n + h/2] around node n (h the cell width):
      -j omega h A_y(y_n) - [Phi(y_n + h/2) - Phi(y_n - h/2)] = -h E_y^inc(y_n),
  A_y with each triangle lumped into a pulse of width h at its node, Phi from the cells' constant charges.

Every interval integral of the kernel is exact: int_0^x H0^(2)(t) dt = int_0^x J0 - j int_0^x Y0
(scipy.special.itj0y0). Echo width (m): sigma_2D = lim 2 pi r |E_s|^2 / |E_i|^2
= (k / 4) |int (eta J_perp)(y') exp(j k s.r') dy'|^2 for a unit incident field, J_perp the part of the
current across s (TM: all of it; TE: J_y cos theta). Physical optics at broadside gives k w^2.

A plate of side L along its edges seen in the plane across them has, when L >> lambda and the current
over most of the plate is that of the infinite strip (the corners' contribution left out),
sigma_3D ~= (2 L^2 / lambda) sigma_2D (`plate_rcs_dbsm`).
"""
from __future__ import annotations

import math

import numpy as np
from scipy.special import itj0y0


def _int_h02(t: np.ndarray) -> np.ndarray:
    """int_0^t H0^(2)(|u|) du [...] complex for real t of either sign (odd in t)."""
    a = np.abs(t)
    ij, iy = itj0y0(a)
    return np.sign(t) * (ij - 1j * iy)


def _kernel_integral(k: float, y: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """int_a^b G(y - y') dy' [broadcast of y, a, b] complex (m), G = H0^(2)(k |y - y'|) / (4 j)."""
    return (_int_h02(k * (y - a)) - _int_h02(k * (y - b))) / (4j * k)


def strip_echo_width(width_m: float, freq_hz: float, theta_deg, polarisation: str, cells: int | None = None
                     ) -> np.ndarray:
    """Monostatic echo width sigma_2D [A] (m) of the PEC strip (module docstring) at angles theta_deg [A]
    from its normal; polarisation "TM" (E along the edges) or "TE" (H along the edges); cells: the number of
    cells across the strip (default: 80 per wavelength, at least 80)."""
    lam = 299_792_458.0 / freq_hz
    k = 2 * math.pi / lam
    n = cells or max(80, int(math.ceil(80 * width_m / lam)))
    h = width_m / n
    nodes = -width_m / 2 + h * np.arange(n + 1)                      # [n + 1]
    centres = 0.5 * (nodes[:-1] + nodes[1:])                        # [n]
    theta = np.radians(np.atleast_1d(np.asarray(theta_deg, dtype=np.float64)))
    phase = np.exp(1j * k * np.outer(np.sin(theta), nodes if polarisation == "TE" else centres))  # [A, .]
    if polarisation == "TM":
        z = 1j * k * _kernel_integral(k, centres[:, None], nodes[None, :-1], nodes[None, 1:])       # [n, n]
        cur = np.linalg.solve(z, phase.T)                             # eta J_z [n, A] for E_z^inc = phase
        rad = h * np.sinc(k * h * np.sin(theta) / (2 * math.pi))        # int_cell exp(j k y sin) / its centre
        field = rad * np.einsum("ma,am->a", cur, phase)
    elif polarisation == "TE":
        inner = nodes[1:-1]                                            # unknowns: eta J_y at the interior nodes
        # vector potential at node n from the triangle of node m, lumped into a pulse of width h at node m
        a_mat = _kernel_integral(k, inner[:, None], inner[None] - h / 2, inner[None] + h / 2)       # [n-1, n-1]
        # scalar potential at the test pulses' ends (the cells' centres) per unit charge of each cell
        q = _kernel_integral(k, centres[:, None], nodes[None, :-1], nodes[None, 1:])               # [n, n]
        dq = q[1:] - q[:-1]                                            # [n-1 (test node), n (cell)]
        # h dJ/dy on cell c (nodes c, c+1) from the interior unknowns (J = 0 at the two edges): [n, n-1]
        d = np.zeros((n, n - 1))
        d[np.arange(n - 1), np.arange(n - 1)] = 1.0                      # + J at node c + 1
        d[np.arange(n - 1) + 1, np.arange(n - 1)] = -1.0                 # - J at node c
        # -j omega h A - [Phi] with rho = -(dJ/dy) / (j omega), in units of eta J: omega mu = k eta, 1 / (omega eps) = eta / k
        z = -1j * k * h * a_mat + dq @ d / (1j * k * h)
        e_inc = -np.cos(theta)[None, :] * phase[:, 1:-1].T               # E_y^inc at the interior nodes [n-1, A]
        cur = np.linalg.solve(z, -h * e_inc)                             # eta J_y [n-1, A]
        rad = h * np.sinc(k * h * np.sin(theta) / (2 * math.pi)) ** 2     # int of a triangle x exp(j k y sin)
        field = np.cos(theta) * rad * np.einsum("ma,am->a", cur, phase[:, 1:-1])
    else:
        raise ValueError(f"strip_mom: polarisation must be 'TM' or 'TE', not {polarisation!r}")
    return k / 4 * np.abs(field) ** 2


def plate_rcs_dbsm(side_m: float, freq_hz: float, theta_deg, polarisation: str, cells: int | None = None
                   ) -> np.ndarray:
    """sigma_3D (dBsm) [A] of a square PEC plate of side side_m in the principal plane across two of its
    edges, from the strip of the same width: (2 L^2 / lambda) sigma_2D (module docstring)."""
    lam = 299_792_458.0 / freq_hz
    s2 = strip_echo_width(side_m, freq_hz, theta_deg, polarisation, cells)
    return 10 * np.log10(np.maximum(2 * side_m**2 / lam * s2, 1e-30))
