"""The steps of the reproduce targets as data: command lines, their inputs and outputs, their code.

A target function (targets.py) declares its steps on a Plan and returns a Table whose cells read
the steps' results later (lazily). The Snakemake workflow (workflow/Snakefile) turns every Step
into a rule: the command line and the code version are rule params, so a changed config value
(spelled out as `--set` in the command), a changed default in configs/*.toml or a changed source
file of the command reruns that step, and Snakemake reruns what depends on its outputs. The same
Plan, built again after the steps ran, fills the tables from the results JSON and from Snakemake's
benchmark files (OUT/benchmarks/<label>.tsv, the wall time of every step).

Commands name `rfir` and `python` without a path (the workflow puts the interpreter's folder first
on PATH) and files relative to the repository root, so no machine path enters a rule's params.
"""
from __future__ import annotations

import csv
import hashlib
import json
import re
import shlex
from dataclasses import dataclass, field
from pathlib import Path

from rfir_core.errors import StageError

ROOT = Path(__file__).resolve().parents[2]

# The source files a command's results depend on, per command (paths relative to the repository
# root; folders mean every *.py / *.toml / *.cpp / *.cu / *.h below). A change in any of them
# changes the step's code version and reruns it. Everything reads src/rfir_cli (artifacts, config).
_CORE = ("src/rfir_cli", "configs/general.toml")
_MODEL = ("stages/model", "ext/rfir_tracer", "ext/csrc")
# the simulators use the model package for its material laws only (rfir_stages.po.facet_materials): a change
# of the fitted model must not regenerate their data
_MATERIAL_LAWS = ("stages/model/__init__.py", "src/rfir_core/physics/materials.py")
CODE: dict[str, tuple[str, ...]] = {
    "simulate": (*_CORE, "stages/simulate", "stages/po", "stages/render", "stages/model/split_protocols.py", *_MATERIAL_LAWS,
                 "configs/simulate.toml"),
    "mesh-gaussians": (*_CORE, "stages/geom", "configs/geom.toml"),
    "calibrate": (*_CORE, "stages/calibrate", "configs/calibrate.toml"),
    "geom": (*_CORE, "stages/geom", "stages/render", "configs/geom.toml"),
    "rf-fit": (*_CORE, *_MODEL, "stages/rf_fit", "configs/rf_fit.toml", "configs/recipes"),
    "predict": (*_CORE, *_MODEL, "stages/rf_fit", "stages/predict", "configs/rf_fit.toml", "configs/predict.toml",
                "configs/recipes"),
    "scripts/edit_validate.py": (*_CORE, *_MODEL, "scripts/edit_validate.py", "stages/rf_fit", "stages/predict",
                                 "stages/edit", "stages/diagnose", "configs/rf_fit.toml", "configs/predict.toml"),
    "scripts/diagnose_blind.py": (*_CORE, *_MODEL, "scripts/diagnose_blind.py", "stages/diagnose", "stages/rf_fit",
                                  "stages/predict", "stages/simulate", "stages/po", "configs/rf_fit.toml",
                                  "configs/simulate.toml", "configs/predict.toml"),
    "scripts/fullwave_compare.py": (*_CORE, "scripts/fullwave_compare.py", "stages/fullwave", "stages/po",
                                    *_MATERIAL_LAWS),
    "import": (*_CORE, "stages/importers"),
    "diagnose": (*_CORE, *_MODEL, "stages/diagnose", "stages/rf_fit", "stages/predict", "configs/rf_fit.toml",
                 "configs/predict.toml"),
    "scripts/measured_like.py": ("scripts/measured_like.py", "stages/simulate/measured_like.py",
                                 "stages/simulate/scenes.py", "stages/model/split_protocols.py", "configs/simulate.toml"),
    "scripts/survey_thin.py": ("scripts/survey_thin.py", "stages/reproduce/survey.py"),
    "scripts/baseline_nerf2.py": (*_CORE, "scripts/baseline_nerf2.py", "stages/baselines"),
    "scripts/baseline_wrfgs.py": (*_CORE, "scripts/baseline_wrfgs.py", "stages/baselines"),
    "scripts/baseline_raytrace.py": (*_CORE, "scripts/baseline_raytrace.py", "stages/simulate"),
    "scripts/baseline_sionna_calibrated.py": (*_CORE, "scripts/baseline_sionna_calibrated.py", "stages/baselines",
                                              "stages/simulate", "stages/geom", "stages/rf_fit", "stages/predict",
                                              "configs/simulate.toml"),
}
_SOURCE_SUFFIXES = {".py", ".toml", ".cpp", ".cu", ".h", ".cuh"}


@dataclass
class Step:
    """One command of a target.

    label: unique name (also the log and benchmark file name); argv: the command line (a str element
    "$(...)" is left to the shell, for values read from an input at run time); outputs: the files it
    writes that later steps or tables read (outputs[0] is the main one; a name ending in "/" is a folder);
    threads: cores it uses."""

    label: str
    argv: list[str]
    outputs: list[str]
    threads: int = 1
    inputs: list[str] = field(default_factory=list)

    @property
    def command(self) -> str:
        return " ".join(f'"{a}"' if a.startswith("$(") else shlex.quote(a) for a in self.argv)

    @property
    def code_files(self) -> tuple[str, ...]:
        """The source paths of this command (CODE), found by the first argv word CODE knows."""
        for word in self.argv:
            if word in CODE:
                return CODE[word]
        raise StageError(f"reproduce step '{self.label}': no entry in plan.CODE for its command {self.argv[:4]}")


@dataclass
class Plan:
    """The steps of one or more targets.

    data: folder for generated data and fits; out: folder for tables, JSON, plots, logs, benchmarks
    (both relative to the repository root); quick: the reduced variant (targets read it to pick sizes);
    overrides: the `--set` settings the sizes came from (the tables' JSON records them in their command)."""

    data: Path
    out: Path
    quick: bool = False
    sizes: dict = field(default_factory=dict)          # the variant's table of configs/reproduce.toml
    steps: dict[str, Step] = field(default_factory=dict)
    used: list[str] = field(default_factory=list)      # labels the current target declared, in order
    overrides: list[str] = field(default_factory=list)  # reproduce.<variant>.<key>=value settings over the sizes

    def __post_init__(self) -> None:
        self.data, self.out = Path(self.data), Path(self.out)

    rfir = "rfir"
    python = "python"

    def json_path(self, label: str) -> Path:
        return self.out / "json" / f"{label}.json"

    def benchmark_path(self, label: str) -> Path:
        return self.out / "benchmarks" / f"{label}.tsv"

    def log_path(self, label: str) -> Path:
        return self.out / "logs" / f"{label}.log"

    def step(self, label: str, argv: list, produces: Path, also: tuple = (), threads: int = 1) -> str:
        """Declare a step writing `produces` (and `also`); return its label (for wall times).

        Two targets may declare the same step (same label): the command lines must then agree."""
        argv = [str(a) for a in argv]
        outputs = [str(produces), *(str(p) for p in also)]
        new = Step(label, argv, outputs, threads)
        old = self.steps.get(label)
        if old is not None and (old.argv != new.argv or old.outputs != new.outputs):
            raise StageError(f"reproduce step '{label}' declared twice with different commands:\n  {old.command}\n  "
                             f"{new.command}")
        self.steps.setdefault(label, new)
        if label not in self.used:
            self.used.append(label)
        return label

    def link_inputs(self) -> None:
        """Each step's inputs: the outputs of other steps its command line names (a folder output
        also covers the files below it)."""
        owner = {o.rstrip("/"): s.label for s in self.steps.values() for o in s.outputs}
        for s in self.steps.values():
            found = []
            for word in s.argv:
                for tok in [word, *re.findall(r"[\w./-]+", word)] if word.startswith("$(") else [word]:
                    path = tok.rstrip("/")
                    while path not in owner and "/" in path.strip("/"):
                        path = str(Path(path).parent)
                    if path in owner and owner[path] != s.label:
                        out = next(o for o in self.steps[owner[path]].outputs if o.rstrip("/") == path)
                        if out not in found:
                            found.append(out)
            s.inputs = found

    def wall(self, *labels: str) -> float | None:
        """Summed wall time [s] of steps from their Snakemake benchmark files (None if none measured)."""
        times = [t for t in (read_benchmark(self.benchmark_path(lbl)) for lbl in labels) if t is not None]
        return sum(times) if times else None


def default_dirs(quick: bool) -> tuple[Path, Path]:
    """(data, out) folders of the full or quick variant, relative to the repository root."""
    suffix = "-quick" if quick else ""
    return Path(f"data/reproduce{suffix}"), Path(f"results/reproduce{suffix}")


def read_benchmark(path: Path) -> float | None:
    """Wall seconds (column `s`) of a Snakemake benchmark file (None if missing or unreadable)."""
    try:
        with Path(path).open() as fh:
            row = next(csv.DictReader(fh, delimiter="\t"))
        return float(row["s"])
    except (OSError, StopIteration, KeyError, ValueError):
        return None


def read_json(path: Path) -> dict:
    path = Path(path)
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise StageError(f"cannot read the step result: {exc}", path=path) from exc


def code_version(paths: tuple[str, ...], root: Path = ROOT) -> str:
    """A content hash of the source files under `paths` (relative to root): the step's code version."""
    h = hashlib.sha256()
    for rel in paths:
        p = root / rel
        files = sorted(f for f in p.rglob("*") if f.is_file() and f.suffix in _SOURCE_SUFFIXES) if p.is_dir() else [p]
        for f in files:
            if f.exists() and "__pycache__" not in f.parts:
                h.update(str(f.relative_to(root)).encode() + b"\0" + f.read_bytes() + b"\0")
    return h.hexdigest()[:16]


def rule_name(label: str) -> str:
    """A Snakemake rule name for a step label (letters, digits and underscores)."""
    return "step_" + re.sub(r"\W", "_", label.replace(".", "p"))


def reproduce_command(target: str, quick: bool, overrides: list[str] = (), data: Path | None = None,
                      out: Path | None = None) -> str:
    """The command that makes a target's table: `make reproduce-<target>` (quick: `make reproduce-quick`, which
    makes every quick table); with workflow settings that differ from the defaults (--set overrides, other
    folders), the Snakemake command line that passes them."""
    d, o = default_dirs(quick)
    config = ["quick=true"] if quick else []
    config += [f"set=[{','.join(json.dumps(s) for s in overrides)}]"] if overrides else []
    config += [f"data={data}"] if data is not None and Path(data) != d else []
    config += [f"out={out}"] if out is not None and Path(out) != o else []
    if len(config) == int(quick):
        return "make reproduce-quick" if quick else f"make reproduce-{target}"
    return f"{VENV_SNAKEMAKE} {target} --config " + " ".join(shlex.quote(c) for c in config)


VENV_SNAKEMAKE = ".venv/bin/snakemake -s workflow/Snakefile"


def _first_line(path: str, key: str) -> str:
    """The value of the first `key: value` line of a /proc or /etc file ('' if absent)."""
    try:
        for line in Path(path).read_text().splitlines():
            if line.startswith(key):
                return line.split(":" if ":" in line else "=", 1)[1].strip().strip('"')
    except OSError:
        pass
    return ""


def machine_record() -> dict:
    """The machine this process runs on, as the results page names it: CPU model and cores, memory [GiB],
    GPUs (nvidia-smi's names; "none"), OS, Python and torch versions. Read without importing torch, so the
    Snakemake process that writes the tables stays light."""
    import os
    import platform
    import shutil
    import subprocess
    from importlib import metadata

    gpus = "none"
    if shutil.which("nvidia-smi"):
        try:
            names = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True,
                                   text=True, timeout=20, check=True).stdout.split("\n")
            gpus = ", ".join(n.strip() for n in names if n.strip()) or "none"
        except (OSError, subprocess.SubprocessError):
            pass
    mem_kib = _first_line("/proc/meminfo", "MemTotal").split()
    try:
        torch = metadata.version("torch")
    except metadata.PackageNotFoundError:
        torch = "not installed"
    return {"cpu": _first_line("/proc/cpuinfo", "model name") or platform.processor() or platform.machine(),
            "cores": os.cpu_count(),
            "memory_gib": round(int(mem_kib[0]) / 2**20) if mem_kib else None,
            "gpu": gpus,
            "os": _first_line("/etc/os-release", "PRETTY_NAME") or platform.platform(),
            "python": platform.python_version(), "torch": torch}
