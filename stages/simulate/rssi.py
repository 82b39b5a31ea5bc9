"""RSSI in a room (task "rssi"): T transmitters x R receivers, omni antennas.

Layout (the paper's design, 24 Tx x 440 Rx): transmitters on a 6 x 4 grid at `tx_height_m`,
receivers on a 22 x 20 grid at `rx_height_m`, both inset `margin_m` from the walls; grid points
within `clearance_m` of an object's bounding box (inside a fridge, against a wardrobe) are dropped. One
Sionna solve per transmitter with every receiver as a target, at each frequency.

A survey over several channels (`channels_hz`, e.g. BLE's three advertising channels) reports each link's power
averaged over them: the paths solved at the one frequency are evaluated at every channel (the delay phase
exact, the materials those of the solve frequency, a few percent away) and their powers averaged, so the deep
fades of one frequency's coherent sum fill in as they do in a measurement (docs/simulate.md).
"""
from __future__ import annotations

import numpy as np

from rfir_core.physics.antennas import Antenna
from .solve import PhysicsEffects, combine_paths


def grid_positions(bounds, nx: int, ny: int, z: float, margin_m: float) -> np.ndarray:
    """nx x ny points (x-major) on a horizontal grid inside bounds, at height z."""
    lo, hi = np.asarray(bounds[0], float), np.asarray(bounds[1], float)
    xs = np.linspace(lo[0] + margin_m, hi[0] - margin_m, int(nx))
    ys = np.linspace(lo[1] + margin_m, hi[1] - margin_m, int(ny))
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, float(z))], 1)


def clear_of_objects(spec, points_m: np.ndarray, clearance_m: float) -> np.ndarray:
    """[N] bool: the point (points_m [N, 3], m) lies outside every object's bounding box grown by
    clearance_m (spec: a SceneSpec)."""
    pts = np.asarray(points_m, np.float64)
    ok = np.ones(len(pts), dtype=bool)
    for o in spec.objects:
        lo, hi = o.vertices.min(0) - clearance_m, o.vertices.max(0) + clearance_m
        ok &= ~np.all((pts >= lo) & (pts <= hi), axis=1)
    return ok


def simulate_rssi(scene, tx_pos, rx_pos, freqs_hz, physics: PhysicsEffects, progress, label: str,
                  loop_mode: str = "evaluated", channels_hz=()):
    """Returns channel (T*R, F), power (T*R, F), tx_id, rx_id, num_paths (T*R, F), cap_hits; rows Tx-major.

    cap_hits counts solves whose path buffer reached max_num_paths_per_src (paths may be lost).
    channels_hz [C] Hz (optional): power is the mean over these channels of the paths solved at each
    freqs_hz value (module docstring); channel then keeps the first channel's phase with |channel|^2 = power.
    """
    import sionna.rt as rt

    from .radio_scene import set_devices

    n_t, n_r, n_f = len(tx_pos), len(rx_pos), len(freqs_hz)
    channel = np.zeros((n_t * n_r, n_f), complex)
    power = np.zeros((n_t * n_r, n_f))
    n_paths = np.zeros((n_t * n_r, n_f), int)
    solver = rt.PathSolver()
    solver.loop_mode = loop_mode
    set_devices(scene, tx_pos[:1], rx_pos)
    tx_dev = scene.transmitters["tx0"]
    omni = Antenna("omni")
    kwargs = physics.solver_kwargs(los=True)
    cap_hits = 0
    with progress.task(label, total=n_t * n_f) as bar:
        for k, f in enumerate(freqs_hz):
            scene.frequency = float(f)
            for t in range(n_t):
                tx_dev.position = [float(v) for v in tx_pos[t]]
                paths = solver(scene, **kwargs)
                at = list(channels_hz) or [f]
                out = combine_paths(paths, at, float(f), omni, [omni] * n_r, physics.combine,
                                    max_paths=physics.max_num_paths_per_src)
                cap_hits += int(out.hit_cap)
                rows = slice(t * n_r, (t + 1) * n_r)
                power[rows, k] = out.power.mean(axis=1)
                channel[rows, k] = out.channel[:, 0]
                if channels_hz:   # the first channel's phase, |channel|^2 the band's mean power
                    mag = np.abs(out.channel[:, 0])
                    channel[rows, k] = np.where(mag > 0, out.channel[:, 0] / np.maximum(mag, 1e-300), 1.0) \
                        * np.sqrt(power[rows, k])
                n_paths[rows, k] = out.num_paths
                bar.advance(1)
    tx_id = np.repeat(np.arange(n_t), n_r)
    rx_id = np.tile(np.arange(n_r), n_t)
    return channel, power, tx_id, rx_id, n_paths, cap_hits
