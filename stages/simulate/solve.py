"""One Sionna RT solve -> per-link complex channel and power, with antenna patterns applied.

Combining paths (SIONNA-NOTES): specular, refracted and diffracted paths are summed coherently,
`h = sum a * exp(-j 2 pi f tau)` (`paths.a` excludes the carrier phase). Sionna's diffuse paths
are random samples of the scattering surface: their coherent sum is speckle that changes with
the seed, so by default ("power") they are summed as power (local-mean power):
    P = |h_specular|^2 + sum |a_diffuse|^2
and the stored complex channel keeps the phase of the full coherent sum with its magnitude set
to sqrt(P) (so |channel|^2 = path gain, as the schema requires). With combine = "coherent",
P = |sum over all paths|^2 and channel is that sum.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rfir_core.physics.antennas import Antenna, unit_from_theta_phi
from .radio_scene import C0


@dataclass(frozen=True)
class PhysicsEffects:
    """Solver switches (recorded in provenance)."""

    max_depth: int = 3
    specular: bool = True
    diffuse: bool = True
    refraction: bool = True
    diffraction: bool = False
    samples_per_src: int = 30_000
    max_num_paths_per_src: int = 200_000
    combine: str = "power"  # "power" or "coherent" (see module doc)
    seed: int = 7

    def solver_kwargs(self, los: bool) -> dict:
        return dict(max_depth=int(self.max_depth), samples_per_src=int(self.samples_per_src),
                    max_num_paths_per_src=int(self.max_num_paths_per_src), synthetic_array=True, los=bool(los),
                    specular_reflection=bool(self.specular), diffuse_reflection=bool(self.diffuse),
                    refraction=bool(self.refraction), diffraction=bool(self.diffraction), seed=int(self.seed))


@dataclass
class SolveOutput:
    """Results for one transmitter and R receivers, at F frequencies."""

    channel: np.ndarray  # (R, F) complex
    power: np.ndarray  # (R, F) linear path gain P_R / P_T (antenna gains included)
    num_paths: np.ndarray  # (R,) valid paths
    num_diffuse: np.ndarray  # (R,) diffuse paths
    hit_cap: bool  # a receiver reached max_num_paths_per_src


def _np(x) -> np.ndarray:
    return np.asarray(x)


def _squeeze_rx_path(arr, num_rx: int) -> np.ndarray:
    """Reduce Sionna's per-path arrays to (R, P) for one transmitter and single antennas."""
    a = _np(arr)
    return a.reshape(num_rx, -1) if a.size else np.zeros((num_rx, 0), a.dtype)


def combine_paths(paths, freqs_hz, carrier_hz: float, tx_ant: Antenna, rx_ants: list[Antenna], combine: str,
                  wideband_amplitude: bool = True, max_paths: int | None = None) -> SolveOutput:
    """Combine the paths of a solve with one transmitter into channels at `freqs_hz`.

    Paths were solved at `carrier_hz`. For other frequencies the delay phase is exact
    (exp(-j 2 pi f tau) per path) and the free-space amplitude factor lambda / (4 pi), which
    every path amplitude carries, is rescaled by carrier / f when wideband_amplitude is set;
    material parameters stay those of the carrier.
    """
    import sionna.rt as rt

    freqs = np.atleast_1d(np.asarray(freqs_hz, dtype=np.float64))
    ar, ai = paths.a
    a_full = _np(ar) + 1j * _np(ai)  # [rx, rx_ant, tx, tx_ant, path]
    num_rx = a_full.shape[0]
    if a_full.shape[2] != 1:
        raise ValueError("combine_paths expects one transmitter per solve")
    a = a_full.reshape(num_rx, -1)
    num_p = a.shape[1]
    tau = _squeeze_rx_path(paths.tau, num_rx)
    valid = _squeeze_rx_path(paths.valid, num_rx).astype(bool)
    inter = _np(paths.interactions)  # [depth, rx, tx, path]
    if num_p == 0:
        z = np.zeros((num_rx, len(freqs)))
        return SolveOutput(z.astype(complex), z, np.zeros(num_rx, int), np.zeros(num_rx, int), False)
    inter = inter.reshape(inter.shape[0], num_rx, num_p)
    diffuse = (inter == int(rt.InteractionType.DIFFUSE)).any(axis=0) & valid
    coherent = valid & ~diffuse

    # antenna patterns, per path
    d_t = unit_from_theta_phi(_squeeze_rx_path(paths.theta_t, num_rx), _squeeze_rx_path(paths.phi_t, num_rx))
    d_r = unit_from_theta_phi(_squeeze_rx_path(paths.theta_r, num_rx), _squeeze_rx_path(paths.phi_r, num_rx))
    g_t = tx_ant.gain(d_t)
    g_r = np.stack([ant.gain(d_r[i]) for i, ant in enumerate(rx_ants)]) if rx_ants else np.ones_like(g_t)
    amp = a * np.sqrt(g_t * g_r)
    amp = np.where(valid, amp, 0.0)

    scale = (carrier_hz / freqs) if wideband_amplitude else np.ones_like(freqs)  # (F,)
    phase = np.exp(-2j * math.pi * tau[:, :, None] * freqs[None, None, :])  # (R, P, F)
    terms = amp[:, :, None] * phase * scale[None, None, :]
    h_all = terms.sum(axis=1)
    if combine == "coherent":
        power = np.abs(h_all) ** 2
        channel = h_all
    elif combine == "power":
        h_coh = np.where(coherent[:, :, None], terms, 0.0).sum(axis=1)
        p_diff = (np.abs(np.where(diffuse, amp, 0.0)) ** 2).sum(axis=1)[:, None] * scale[None, :] ** 2
        power = np.abs(h_coh) ** 2 + p_diff
        mag = np.abs(h_all)
        channel = np.where(mag > 0, h_all / np.maximum(mag, 1e-300), 1.0) * np.sqrt(power)
    else:
        raise ValueError(f"combine must be 'power' or 'coherent', got {combine!r}")
    cap = paths_hit_cap(valid, max_paths)
    return SolveOutput(channel, power, valid.sum(1), diffuse.sum(1), cap)


def paths_hit_cap(valid: np.ndarray, cap: int | None = None) -> bool:
    """True when the solve may have stopped at max_num_paths_per_src (paths silently lost)."""
    return bool(cap is not None and valid.sum() >= cap)


def wavelength_m(freq_hz) -> np.ndarray:
    return C0 / np.asarray(freq_hz, dtype=np.float64)


def rcs_dbsm_from_gain(path_gain_lin, range_m, freq_hz, boresight_gain: float) -> np.ndarray:
    """sigma = (4 pi)^3 r^4 P_R / (P_T G_T G_R lambda^2), in dBsm (docs/physics.md section 5.2, step 5)."""
    lam = wavelength_m(freq_hz)
    r = np.asarray(range_m, dtype=np.float64)
    sigma = (4 * math.pi) ** 3 * r[:, None] ** 4 * path_gain_lin / (boresight_gain ** 2 * lam[None, :] ** 2)
    return 10.0 * np.log10(np.maximum(sigma, 1e-300))


def solve_links(scene, tx_pos, rx_pos, freq_hz: float, physics: PhysicsEffects, tx_ant: Antenna | None = None,
                rx_ants: list[Antenna] | None = None, los: bool = True, solver=None, focus=None) -> SolveOutput:
    """One transmitter at tx_pos (3,), receivers rx_pos (R, 3): set devices, solve, combine.

    focus: None, or (axis (3,), cos_cutoff) for focused sampling (object alone in free space).
    """
    import sionna.rt as rt

    from .radio_scene import set_devices
    from .sampling import focused_sampling

    rx_pos = np.atleast_2d(np.asarray(rx_pos, float))
    set_devices(scene, np.atleast_2d(np.asarray(tx_pos, float)), rx_pos)
    scene.frequency = float(freq_hz)
    if solver is None:
        solver = rt.PathSolver()
        solver.loop_mode = "evaluated"
    axis, cos_c = focus if focus is not None else (None, -2.0)
    with focused_sampling(solver, axis, cos_c):
        paths = solver(scene, **physics.solver_kwargs(los=los))
    tx_ant = tx_ant or Antenna("omni")
    rx_ants = rx_ants or [Antenna("omni")] * len(rx_pos)
    return combine_paths(paths, [freq_hz], float(freq_hz), tx_ant, rx_ants, physics.combine)
