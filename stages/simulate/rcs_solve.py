"""One block of monostatic RCS links solved with Sionna: the work of the main process (simulate.workers = 1) and of
each spawned worker (parallel.py) alike, so that rcs.py and parallel.py both import it from here."""
from __future__ import annotations

import numpy as np

from rfir_core.physics.antennas import Antenna
from .sampling import cone_for_sphere, focused_available, focused_sampling
from .solve import PhysicsEffects, combine_paths


class SolverState:
    """A Sionna scene with one Tx and one Rx and a PathSolver, reused across solves."""

    def __init__(self, scene):
        import sionna.rt as rt

        from .radio_scene import set_devices

        self.scene = scene
        self.solver = rt.PathSolver()
        self.solver.loop_mode = "evaluated"  # faster than symbolic for one small solve
        set_devices(scene, np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]))
        self.tx_dev, self.rx_dev = scene.transmitters["tx0"], scene.receivers["rx0"]


def solve_unit(state: SolverState, job: dict, unit, advance=None) -> dict:
    """Solve links `unit[3]` at solve frequency unit[1], output frequencies unit[2]."""
    _, f_solve, f_out, idx = unit
    tx, rx, centre = job["tx"], job["rx"], job["centre"]
    physics: PhysicsEffects = job["physics"]
    use_focus = bool(job["focus"] and focused_available(state.solver))
    kwargs = physics.solver_kwargs(los=False)
    state.scene.frequency = float(f_solve)
    n = len(idx)
    res = {"channel": np.zeros((n, len(f_out)), complex), "power": np.zeros((n, len(f_out))),
           "num_paths": np.zeros(n, int), "num_diffuse": np.zeros(n, int), "cap_hits": 0, "focused": use_focus}
    for j, i in enumerate(idx):
        state.tx_dev.position = [float(v) for v in tx[i]]
        state.rx_dev.position = [float(v) for v in rx[i]]
        mid = 0.5 * (tx[i] + rx[i])
        bore = centre - mid
        ant = Antenna("horn", tuple(bore / np.linalg.norm(bore)), job["hpbw_deg"])
        if use_focus:
            axis, cos_c = cone_for_sphere(tx[i], centre, job["object_radius_m"])
        else:
            axis, cos_c = None, -2.0
        with focused_sampling(state.solver, axis, cos_c):
            paths = state.solver(state.scene, **kwargs)
        out = combine_paths(paths, f_out, float(f_solve), ant, [ant], physics.combine,
                            max_paths=physics.max_num_paths_per_src)
        res["cap_hits"] += int(out.hit_cap)
        res["channel"][j] = out.channel[0]
        res["power"][j] = out.power[0]
        res["num_paths"][j] = out.num_paths[0]
        res["num_diffuse"][j] = out.num_diffuse[0]
        if advance is not None:
            advance(1)
    return res
