"""How each method is run on one row of a reproduce table: its steps, and deferred cells that read its results.

rfir: `rfir rf-fit` then `rfir predict rcs|rssi` (whose JSON also scores the simple baselines on
the same split: nearest aspect, linear interpolation, log-distance, multi-wall, nearest links).
NeRF2-style and WRF-GS-style fields: scripts/baseline_nerf2.py and scripts/baseline_wrfgs.py.
Ray tracing: scripts/baseline_raytrace.py (Sionna RT on a mesh with one guessed ITU material; on a labelled
mesh, ITU materials per label plus a fitted system gain, and a grid of wall materials and thicknesses chosen on
the training links) and scripts/baseline_sionna_calibrated.py (materials per object class calibrated through
Sionna's gradients).
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

from .plan import Plan, read_json
from .tables import Cell

SCRIPTS = Path("scripts")       # relative to the repository root, where the workflow runs


class Result:
    """The results JSON of a step, read when the table is filled; `labels`: the steps its time sums."""

    def __init__(self, plan: Plan, path: Path, *labels: str):
        self.plan, self.path, self.labels = plan, Path(path), labels

    def data(self) -> dict:
        return read_json(self.path)

    def cell(self, key: str = "metrics.mae_db") -> Callable[[], Cell]:
        """A deferred Cell: the value at dotted `key` and the summed wall time of the steps."""
        def read() -> Cell:
            value = self.data()
            for part in key.split("."):
                value = value[part]
            return Cell(value, self.plan.wall(*self.labels))
        return read

    def metric(self, *keys: str) -> Callable[[], Cell]:
        """A deferred Cell without a time: the first of `keys` present in the JSON's metrics (a simple
        baseline scored by rfir's predict)."""
        def read() -> Cell:
            m = self.data()["metrics"]
            return Cell(next((m[k] for k in keys if k in m), None))
        return read


def set_args(pairs: dict | None) -> list[str]:
    """`--set key=value` arguments for the rfir CLI."""
    out: list[str] = []
    for k, v in (pairs or {}).items():
        out += ["--set", f"{k}={v}"]
    return out


def rfir_rcs(r: Plan, label: str, scene: Path, meas: Path, protocol: str, freq_hz: float,
             sets: dict | None = None) -> Result:
    """rf-fit (the physical model, its step counts from the config or `sets`) on the protocol's training
    rows at one frequency, predict rcs on its test rows."""
    rf = r.data / "fits" / f"{label}.h5"
    t_fit = r.step(f"{label}__rfir_fit", [r.rfir, "--seed", "0", *set_args(sets), "rf-fit", str(scene), str(meas),
                                         "-o", str(rf), "--split", protocol, "--freq-hz", f"{freq_hz:g}"], rf)
    return rfir_predict_rcs(r, label, rf, meas, t_fit)


def rfir_predict_rcs(r: Plan, label: str, rf: Path, meas: Path, t_fit: str, freqs_hz: list[float] = ()) -> Result:
    """`rfir predict rcs` of a fit (step `t_fit`) on the test rows of its protocol; freqs_hz: the
    measured frequencies to predict (default: the fitted ones; a physical model predicts any)."""
    j = r.json_path(f"{label}__rfir")
    freqs = ["--freqs", ",".join(f"{f:g}" for f in freqs_hz)] if freqs_hz else []
    t_pred = r.step(f"{label}__rfir_predict", [r.rfir, "--seed", "0", "predict", "rcs", str(rf), "-o",
                                               str(r.data / "fits" / f"{label}_pred.h5"), "--measurements", str(meas),
                                               *freqs, "--plots", str(r.out / "plots" / label), "--results", str(j)], j)
    return Result(r, j, t_fit, t_pred)


def rfir_rssi(r: Plan, label: str, scene: Path, meas: Path, split: str, sets: dict | None = None) -> Result:
    """rf-fit of the room model (split "random": the file's column; "holdout_tx": 4 unseen Tx) and
    predict rssi on the test rows (its JSON also scores the simple baselines on the same split)."""
    fits = r.data / "fits"
    rf = fits / f"{label}.h5"
    sets = dict(sets or {})
    if split == "holdout_tx":
        sets["rf_fit.rssi.split"] = "holdout_tx"
    t_fit = r.step(f"{label}__rfir_fit", [r.rfir, "--seed", "0", *set_args(sets), "rf-fit",
                                         str(scene), str(meas), "-o", str(rf)], rf)
    j = r.json_path(f"{label}__rfir")
    t_pred = r.step(f"{label}__rfir_predict", [r.rfir, "--seed", "0", "predict", "rssi", str(rf),
                                               "--measurements", str(meas), "-o", str(fits / f"{label}_pred.h5"),
                                               "--plots", str(r.out / "plots" / label), "--results", str(j)], j)
    return Result(r, j, t_fit, t_pred)


def _baseline(r: Plan, label: str, method: str, argv: list[str]) -> Callable[[], Cell]:
    """A baseline script's step; its deferred cell."""
    j = r.json_path(f"{label}__{method}")
    step = r.step(f"{label}__{method}", [r.python, *argv, "--results", str(j)], j, threads=2)

    def read() -> Cell:
        d = read_json(j)
        return Cell(d["metrics"]["mae_db"], r.wall(step) or d.get("wall_time_s"))
    return read


def nerf2(r: Plan, label: str, meas: Path, task: str, split: str, minutes: float, freq_index: int = 0,
          epochs: int | None = None) -> Callable[[], Cell]:
    """The NeRF2-style field; split: random/holdout_tx (rssi) or an rf-fit protocol (rcs)."""
    argv = [str(SCRIPTS / "baseline_nerf2.py"), str(meas), "--minutes", f"{minutes:g}", "--threads", "2",
            "--freq-index", str(freq_index)]
    # rcs: few rays and samples, small batches, epochs bounded by the budget only (more steps in the
    # budget; docs/baselines.md "NeRF2")
    if task == "rssi":
        argv += ["--split", split]
    else:
        argv += ["--task", "rcs", "--protocol", split, "--n-dirs", "16", "--n-samples", "12", "--batch", "32"]
        epochs = 100000 if epochs is None else epochs
    if epochs is not None:
        argv += ["--epochs", str(epochs)]
    return _baseline(r, label, "nerf2", argv)


def wrfgs(r: Plan, label: str, meas: Path, scene: Path, task: str, split: str, minutes: float,
          freq_index: int = 0, epochs: int | None = None) -> Callable[[], Cell]:
    """The WRF-GS-style Gaussian field (signal entangled with the source) on the scene's Gaussians."""
    argv = [str(SCRIPTS / "baseline_wrfgs.py"), str(meas), "--scene", str(scene), "--task", task,
            "--minutes", f"{minutes:g}", "--threads", "2", "--freq-index", str(freq_index)]
    argv += ["--split", split] if task == "rssi" else ["--protocol", split]
    if epochs is not None:
        argv += ["--epochs", str(epochs)]
    return _baseline(r, label, "wrfgs", argv)


def raytrace(r: Plan, label: str, mesh: Path, meas: Path, material: str = "concrete") -> Callable[[], Cell]:
    """Sionna RT on `mesh` with one ITU material for everything, scored on the file's test split."""
    j = r.json_path(f"{label}__raytrace")
    step = r.step(f"{label}__raytrace", [r.python, str(SCRIPTS / "baseline_raytrace.py"), str(mesh), str(meas),
                                        "--material", material, "--results", str(j)], j)
    return Result(r, j, step).cell("mae_db")


def raytrace_calibrated(r: Plan, label: str, mesh: Path, meas: Path, split: str, iterations: int,
                        links: int) -> Callable[[], Cell]:
    """Sionna RT on `mesh`, one material per object class (one for all on a mesh without labels) calibrated
    by gradient descent on `links` training links of the split, scored on its test links."""
    j = r.json_path(f"{label}__raytrace_calibrated")
    step = r.step(f"{label}__raytrace_calibrated",
                  [r.python, str(SCRIPTS / "baseline_sionna_calibrated.py"), str(mesh), str(meas), "--split", split,
                   "--iterations", str(iterations), "--links", str(links), "--results", str(j)], j)
    return Result(r, j, step).cell()


def raytrace_sweep(r: Plan, label: str, mesh: Path, meas: Path, wall_materials: str | None = None,
                   wall_thickness: str | None = None) -> tuple[Path, str]:
    """Sionna RT on a labelled mesh once per candidate material set (the labels' ITU materials, then each wall
    material x thickness of the grid: comma lists, None = the script's default grid) for every link of `meas`:
    (the sweep's npz, its step). Files with the same links and other splits share it."""
    sweep = r.data / "fits" / f"{label}_raytrace_sweep.npz"
    grid = ((["--wall-materials", wall_materials] if wall_materials else [])
            + (["--wall-thickness", wall_thickness] if wall_thickness else []))
    step = r.step(f"{label}__raytrace_sweep", [r.python, str(SCRIPTS / "baseline_raytrace.py"), "sweep", str(mesh),
                                               str(meas), "--out", str(sweep), *grid], sweep)
    return sweep, step


def raytrace_gain(r: Plan, label: str, sweep: Path, sweep_step: str, meas: Path) -> Result:
    """A sweep scored on the split of `meas`: its JSON's metrics.mae_db (the labels' ITU materials plus one
    system gain fitted on the training links) and metrics.calibrated_mae_db (the grid's set of lowest training
    MAE); the time of each cell includes the whole sweep."""
    j = r.json_path(f"{label}__raytrace_gain")
    step = r.step(f"{label}__raytrace_gain", [r.python, str(SCRIPTS / "baseline_raytrace.py"), "score", str(sweep),
                                              str(meas), "--results", str(j)], j)
    return Result(r, j, sweep_step, step)
