"""How each method is run on one row of a reproduce table, returning its Cell and its JSON.

rfir: `rfir rf-fit` then `rfir predict rcs|rssi` (whose JSON also scores the simple baselines on
the same split: nearest aspect, linear interpolation, log-distance, multi-wall, nearest links).
NeRF2-style and WRF-GS-style fields: scripts/baseline_nerf2.py and scripts/baseline_wrfgs.py.
Ray tracing: scripts/baseline_raytrace.py (Sionna RT on a mesh with one guessed ITU material).
"""
from __future__ import annotations

from pathlib import Path

from rfir_cli.errors import StageError

from .runner import Runner, read_json
from .tables import Cell

SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"


def set_args(pairs: dict | None) -> list[str]:
    """`--set key=value` arguments for the rfir CLI."""
    out: list[str] = []
    for k, v in (pairs or {}).items():
        out += ["--set", f"{k}={v}"]
    return out


def rfir_rcs(r: Runner, label: str, scene: Path, meas: Path, protocol: str, freq_hz: float,
             iterations: int, sets: dict | None = None) -> tuple[Cell, dict]:
    """rf-fit on the protocol's training rows at one frequency, predict rcs on its test rows."""
    fits = r.data / "fits"
    fits.mkdir(parents=True, exist_ok=True)
    rf = fits / f"{label}.h5"
    t_fit = r.step(f"{label}__rfir_fit", [r.rfir, "--seed", "0", *set_args(sets), "rf-fit", str(scene), str(meas),
                                         "-o", str(rf), "--split", protocol, "--freq-hz", f"{freq_hz:g}",
                                         "--iterations", str(iterations)], rf)
    j = r.json_path(f"{label}__rfir")
    t_pred = r.step(f"{label}__rfir_predict", [r.rfir, "--seed", "0", "predict", "rcs", str(rf), "-o",
                                               str(fits / f"{label}_pred.h5"), "--measurements", str(meas),
                                               "--plots", str(r.out / "plots" / label), "--results", str(j)], j)
    d = read_json(j)
    return Cell(d["metrics"]["mae_db"], t_fit + t_pred), d


def rfir_rssi(r: Runner, label: str, scene: Path, meas: Path, split: str, iterations: int | None,
              sets: dict | None = None) -> tuple[Cell, dict]:
    """`rfir --recipe rssi` fit (split "random": the file's column; "holdout_tx": 4 unseen Tx) and score."""
    fits = r.data / "fits"
    fits.mkdir(parents=True, exist_ok=True)
    rf = fits / f"{label}.h5"
    sets = dict(sets or {})
    if split == "holdout_tx":
        sets["rf_fit.rssi.split"] = "holdout_tx"
    if iterations is not None:
        sets["rf_fit.iterations"] = iterations
    t_fit = r.step(f"{label}__rfir_fit", [r.rfir, "--seed", "0", "--recipe", "rssi", *set_args(sets), "rf-fit",
                                         str(scene), str(meas), "-o", str(rf)], rf)
    j = r.json_path(f"{label}__rfir")
    t_pred = r.step(f"{label}__rfir_predict", [r.rfir, "--seed", "0", "--recipe", "rssi", "predict", "rssi", str(rf),
                                               "--measurements", str(meas), "-o", str(fits / f"{label}_pred.h5"),
                                               "--plots", str(r.out / "plots" / label), "--results", str(j)], j)
    d = read_json(j)
    return Cell(d["metrics"]["mae_db"], t_fit + t_pred), d


def _baseline(r: Runner, label: str, method: str, argv: list[str]) -> Cell:
    """A baseline that fails leaves a "failed" cell (the run goes on, and ends with a non-zero exit)."""
    j = r.json_path(f"{label}__{method}")
    try:
        wall = r.step(f"{label}__{method}", [r.python, *argv, "--results", str(j)], j)
    except StageError as exc:
        r.failed.append(str(exc))
        return Cell(note=f"failed (logs/{label}__{method}.log)")
    d = read_json(j)
    return Cell(d["metrics"]["mae_db"], wall or d.get("wall_time_s"))


def nerf2(r: Runner, label: str, meas: Path, task: str, split: str, minutes: float, freq_index: int = 0,
          epochs: int | None = None) -> Cell:
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


def wrfgs(r: Runner, label: str, meas: Path, scene: Path, task: str, split: str, minutes: float,
          freq_index: int = 0, epochs: int | None = None) -> Cell:
    """The WRF-GS-style Gaussian field (signal entangled with the source) on the scene's Gaussians."""
    argv = [str(SCRIPTS / "baseline_wrfgs.py"), str(meas), "--scene", str(scene), "--task", task,
            "--minutes", f"{minutes:g}", "--threads", "2", "--freq-index", str(freq_index)]
    argv += ["--split", split] if task == "rssi" else ["--protocol", split]
    if epochs is not None:
        argv += ["--epochs", str(epochs)]
    return _baseline(r, label, "wrfgs", argv)


def raytrace(r: Runner, label: str, mesh: Path, meas: Path, material: str = "concrete") -> Cell:
    """Sionna RT on `mesh` with one ITU material for everything, scored on the file's test split."""
    j = r.json_path(f"{label}__raytrace")
    wall = r.step(f"{label}__raytrace", [r.python, str(SCRIPTS / "baseline_raytrace.py"), str(mesh), str(meas),
                                        "--material", material, "--results", str(j)], j)
    return Cell(read_json(j)["mae_db"], wall)
