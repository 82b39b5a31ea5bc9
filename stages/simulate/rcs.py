"""Monostatic RCS on a turntable (tasks "rcs" and "wideband").

Geometry (artifact convention): the object stays fixed, centred at the origin. Turntable aspect
theta (object rotated counter-clockwise about +z) is represented by the radar at azimuth
-theta, range r, at the object's centre height. Tx and Rx are the same radar, separated
vertically by `separation_m` (2 mm: with exactly co-located Tx and Rx Sionna loses some returns,
SIONNA-NOTES). Both are horns with boresight at the object's centre. No room, no direct path
(`los=False`): the object alone.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .rcs_solve import SolverState, solve_unit
from .solve import PhysicsEffects


@dataclass
class RadarGrid:
    aspects_rad: np.ndarray  # (A,)
    ranges_m: np.ndarray  # (Rg,)
    centre: np.ndarray  # (3,)
    separation_m: float = 0.002

    def links(self):
        """Rows ordered range-major: (aspect_rad, range_m, radar_pos) for every link (L = Rg * A)."""
        asp = np.tile(self.aspects_rad, len(self.ranges_m))
        rng = np.repeat(self.ranges_m, len(self.aspects_rad))
        pos = np.stack([rng * np.cos(-asp), rng * np.sin(-asp), np.zeros_like(asp)], 1) + self.centre
        return asp, rng, pos

    def tx_rx(self):
        _, _, pos = self.links()
        off = np.array([0.0, 0.0, self.separation_m / 2])
        return pos + off, pos - off


@dataclass
class RcsRaw:
    channel: np.ndarray  # (L, F) complex
    power: np.ndarray  # (L, F)
    num_paths: np.ndarray  # (L, n_solves_per_link)
    num_diffuse: np.ndarray
    focused: bool
    solves: int
    cap_hits: int = 0  # solves that reached max_num_paths_per_src


def simulate_monostatic(scene, grid: RadarGrid, object_radius_m: float, solve_freqs_hz, out_freqs_per_solve,
                        physics: PhysicsEffects, hpbw_deg: float, focus: bool, progress, label: str,
                        workers: int = 1, radio_xml=None, material_effects=None,
                        worker_timeout_s: float = 900.0) -> RcsRaw:
    """Solve every link at every solve frequency.

    solve_freqs_hz: (S,) frequencies at which Sionna is re-run (materials re-evaluated).
    out_freqs_per_solve: list of S arrays: the output frequencies computed from each solve
    (for narrowband tasks just [f]); concatenated in order they form the F axis.
    workers > 1: the (solve frequency, block of links) units go to that many 'spawn' worker
    processes, each loading `radio_xml` itself (see `parallel.py`); the results are the same
    arrays as workers = 1 (every solve is seeded and independent of the others).
    """
    tx, rx = grid.tx_rx()
    n_links = len(tx)
    out_freqs_per_solve = [np.atleast_1d(np.asarray(o, float)) for o in out_freqs_per_solve]
    out_sizes = [len(o) for o in out_freqs_per_solve]
    cols = np.concatenate([[0], np.cumsum(out_sizes)])
    n_f = int(cols[-1])
    channel = np.zeros((n_links, n_f), complex)
    power = np.zeros((n_links, n_f))
    n_paths = np.zeros((n_links, len(solve_freqs_hz)), int)
    n_diff = np.zeros_like(n_paths)
    total = n_links * len(solve_freqs_hz)
    job = dict(tx=tx, rx=rx, centre=np.asarray(grid.centre, float), object_radius_m=float(object_radius_m),
               physics=physics, hpbw_deg=float(hpbw_deg), focus=bool(focus))
    units = [(s, float(f), out_freqs_per_solve[s], idx) for s, f in enumerate(solve_freqs_hz)
             for idx in _link_blocks(n_links, workers)]
    cap_hits = 0
    use_focus = None

    def store(unit, res):
        nonlocal cap_hits, use_focus
        s, _, _, idx = unit
        channel[idx, cols[s]:cols[s + 1]] = res["channel"]
        power[idx, cols[s]:cols[s + 1]] = res["power"]
        n_paths[idx, s] = res["num_paths"]
        n_diff[idx, s] = res["num_diffuse"]
        cap_hits += int(res["cap_hits"])
        use_focus = res["focused"] if use_focus is None else (use_focus and res["focused"])

    with progress.task(label, total=total) as bar:
        if workers <= 1:
            import drjit as dr

            threads = dr.thread_count()
            dr.set_thread_count(1)  # as the workers: with > 1 thread a solve is not reproducible (parallel.py)
            try:
                state = SolverState(scene)
                for unit in units:
                    store(unit, solve_unit(state, job, unit, bar.advance))
            finally:
                dr.set_thread_count(threads)
        else:
            from .parallel import run_units

            if radio_xml is None:
                raise ValueError("workers > 1 needs the radio scene's XML path")
            run_units(units, job, str(radio_xml), material_effects, workers, worker_timeout_s,
                      lambda unit, res: (store(unit, res), bar.advance(len(unit[3]))))
    return RcsRaw(channel, power, n_paths, n_diff, bool(use_focus), total, cap_hits)


def _link_blocks(n_links: int, workers: int) -> list[np.ndarray]:
    """Link indices in contiguous blocks: one block in-process; with workers, small enough blocks
    (<= 60 links, >= 2 per worker) that the workers stay balanced and progress moves."""
    if workers <= 1:
        return [np.arange(n_links)]
    size = max(1, min(60, math.ceil(n_links / (2 * workers))))
    return [np.arange(i, min(n_links, i + size)) for i in range(0, n_links, size)]


def wideband_plan(centre_hz: float, bandwidth_hz: float, num_freqs: int, num_anchors: int):
    """Output frequencies and the anchor (re-solved) frequency of each.

    The band is split into num_anchors equal sub-bands; each is computed from one solve at its
    centre frequency. Returns (anchor_freqs (S,), list of S arrays of output freqs).
    """
    freqs = np.linspace(centre_hz - bandwidth_hz / 2, centre_hz + bandwidth_hz / 2, int(num_freqs))
    num_anchors = max(1, min(int(num_anchors), len(freqs)))
    chunks = np.array_split(freqs, num_anchors)
    anchors = np.array([0.5 * (c[0] + c[-1]) for c in chunks])
    return anchors, chunks


def object_radius(spec) -> float:
    """Radius of the sphere about the origin that encloses every vertex."""
    allv = np.concatenate([o.vertices for o in spec.objects])
    return float(np.linalg.norm(allv, axis=1).max())


def aspect_grid(step_deg: float, count: int | None = None) -> np.ndarray:
    n = int(round(360.0 / step_deg)) if count is None else int(count)
    return np.deg2rad(np.arange(n) * step_deg) % (2 * math.pi)
