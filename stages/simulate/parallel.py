"""Sionna RCS solves in worker processes (`simulate.workers`, default 2).

Why 'spawn' and not fork (the earlier attempt that hung): Dr.Jit's LLVM backend keeps a thread
pool (nanothread) and JIT state. A forked child inherits the parent's memory but not its
threads; a child forked after Dr.Jit has started (the parent loaded the scene) waits on locks and
workers that do not exist, or crashes in the JIT. With `multiprocessing.Pool`, a worker that dies
takes its task with it and `Pool.map` waits forever: that is the hang. Here:

- workers are started with the 'spawn' method (fresh interpreters, nothing inherited) and each
  loads the radio scene from the exported XML itself (`_init_worker`);
- each worker runs Dr.Jit with one thread (`drjit.set_thread_count`) so N workers use N cores
  instead of N x cores threads fighting over 2 cores. One thread is also what makes a solve
  reproducible: with several Dr.Jit threads a repeated solve can differ by hundredths of a dB (diffuse
  samples are gathered in thread order); with one thread repeats, block splits and separate processes
  give bit-identical arrays. The in-process
  path (workers = 1) therefore also solves with one Dr.Jit thread;
- `concurrent.futures.ProcessPoolExecutor` marks the pool broken when a worker dies
  (`BrokenProcessPool`), and the main process waits with a timeout: a dead, failing or silent
  worker becomes a `StageError` naming the cause, and the remaining workers are terminated.
"""
from __future__ import annotations

import multiprocessing as mp
import os
import traceback
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool

from rfir_core.errors import StageError

_STATE = {}


def _init_worker(xml_path: str, effects, threads: int) -> None:
    os.environ.setdefault("OMP_NUM_THREADS", str(threads))
    import drjit as dr

    dr.set_thread_count(int(threads))
    from .radio_scene import load_radio_xml
    from .rcs_solve import SolverState

    _STATE["state"] = SolverState(load_radio_xml(xml_path, 2.4e9, effects))


def _work(job: dict, unit):
    from .rcs_solve import solve_unit

    try:
        return solve_unit(_STATE["state"], job, unit)
    except BaseException as exc:  # keep the worker's traceback for the error message
        raise RuntimeError(f"{type(exc).__name__}: {exc}\n{traceback.format_exc()}") from None


def run_units(units, job, xml_path: str, effects, workers: int, timeout_s: float, on_result,
              threads_per_worker: int = 1) -> None:
    """Run `solve_unit` for every unit in `workers` spawned processes; call on_result(unit, result)
    in the main process as results arrive. Raises StageError when a worker fails, dies, or
    nothing finishes within timeout_s seconds."""
    ctx = mp.get_context("spawn")
    ex = ProcessPoolExecutor(max_workers=int(workers), mp_context=ctx, initializer=_init_worker,
                             initargs=(xml_path, effects, int(threads_per_worker)))
    ok = False
    try:
        pending = {ex.submit(_work, job, u): u for u in units}
        while pending:
            done, _ = wait(pending, timeout=timeout_s, return_when=FIRST_COMPLETED)
            if not done:
                raise StageError(f"simulate: no Sionna worker finished a block within {timeout_s:.0f} s "
                                 f"({len(pending)} of {len(units)} blocks left); raise simulate.worker_timeout_s "
                                 "or run with simulate.workers=1")
            for fut in done:
                unit = pending.pop(fut)
                try:
                    res = fut.result()
                except BrokenProcessPool as exc:
                    raise StageError(f"simulate: a Sionna worker process died ({exc}). Causes: out of memory, "
                                     "or a Python script calling rfir_stages.simulate.run without an "
                                     "`if __name__ == '__main__':` guard (workers are spawned and re-import "
                                     "__main__); try simulate.workers=1") from None
                except Exception as exc:  # noqa: BLE001 - a worker's error
                    raise StageError(f"simulate: a Sionna worker failed on solve frequency {unit[1] / 1e9:g} GHz, "
                                     f"links {int(unit[3][0])}..{int(unit[3][-1])}: {exc}") from None
                on_result(unit, res)
        ok = True
    finally:
        if ok:
            ex.shutdown(wait=True)
        else:
            procs = list(getattr(ex, "_processes", {}).values())  # the workers this call started
            ex.shutdown(wait=False, cancel_futures=True)
            for p in procs:
                if p.is_alive():
                    p.terminate()
            for p in procs:
                p.join(timeout=10)
