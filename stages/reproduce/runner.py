"""Running the steps of a reproduce target: commands, their logs, wall times and a cache.

A step is a command line plus the file it produces. If that file exists and this data folder
holds the step's stamp (DATA/steps/<label>.done, written when the step succeeded here, holding its
command line) for the same command line (--force ignores both), the step is skipped and its
earlier wall time is reused, so an interrupted
`make reproduce` resumes where it stopped and a table can be rebuilt without rerunning anything.
The stamp lives beside the generated data, which is never committed: results that came with a
clone (results/reproduce/json) do not count as done, so a fresh clone reruns every step.
"""
from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

from rfir_cli.errors import StageError


@dataclass
class Runner:
    """Runs steps for one reproduce invocation.

    data: folder for generated data and fits; out: folder for tables, logs and times.json.
    quick: the reduced variant (targets read it to pick sizes)."""

    data: Path
    out: Path
    quick: bool = False
    force: bool = False
    echo: bool = True
    times: dict = field(default_factory=dict)   # step label -> wall seconds (all runs, from times.json)
    used: set = field(default_factory=set)      # labels of the steps the current target went through
    failed: list = field(default_factory=list)  # errors of baseline steps that failed (the run went on)

    def __post_init__(self) -> None:
        self.data, self.out = Path(self.data), Path(self.out)
        self.data.mkdir(parents=True, exist_ok=True)
        (self.out / "logs").mkdir(parents=True, exist_ok=True)
        (self.out / "json").mkdir(parents=True, exist_ok=True)
        path = self.out / "times.json"
        if path.exists():
            self.times = json.loads(path.read_text())

    @property
    def python(self) -> str:
        return sys.executable

    @property
    def rfir(self) -> str:
        """The `rfir` entry point installed beside this Python."""
        exe = Path(sys.executable).parent / "rfir"
        return str(exe) if exe.exists() else "rfir"

    def json_path(self, label: str) -> Path:
        return self.out / "json" / f"{label}.json"

    def step(self, label: str, argv: list[str], produces: Path, env: dict | None = None) -> float:
        """Run argv unless `produces` exists; return the step's wall time [s] (0 if unknown).

        The command's output goes to OUT/logs/<label>.log; a failure raises StageError naming it."""
        produces = Path(produces)
        self.used.add(label)
        stamp = self.data / "steps" / f"{label}.done"
        command = shlex.join(argv)
        if produces.exists() and _stamped_command(stamp) == command and not self.force:
            self._say(f"[dim]cached[/] {label}")
            return float(self.times.get(label, 0.0))
        log = self.out / "logs" / f"{label}.log"
        self._say(f"[bold]run[/] {label}: {command if len(command) < 400 else command[:400] + ' ...'}")
        t0 = time.perf_counter()
        with log.open("w") as fh:
            fh.write(command + "\n")
            fh.flush()
            proc = subprocess.run(argv, stdout=fh, stderr=subprocess.STDOUT, env={**os.environ, **(env or {})})
        wall = time.perf_counter() - t0
        if proc.returncode != 0 or not produces.exists():
            why = f"exit {proc.returncode}" if proc.returncode else f"it did not write {produces}"
            raise StageError(f"step '{label}' failed ({why}); see the log", path=log)
        self.times[label] = wall
        self._write_times()
        stamp.parent.mkdir(parents=True, exist_ok=True)
        stamp.write_text(json.dumps({"command": command, "produces": str(produces), "wall_s": wall}) + "\n")
        self._say(f"    done in {wall:.0f} s")
        return wall

    def _write_times(self) -> None:
        """Merge into times.json (another target may run at the same time and add its own steps)."""
        path = self.out / "times.json"
        on_disk = json.loads(path.read_text()) if path.exists() else {}
        self.times = {**on_disk, **self.times}
        tmp = path.with_name(f"times.json.{os.getpid()}.tmp")
        tmp.write_text(json.dumps(self.times, indent=1, sort_keys=True) + "\n")
        tmp.replace(path)

    def _say(self, text: str) -> None:
        if self.echo:
            from rich.console import Console

            Console(stderr=True, highlight=False).print(text)


def _stamped_command(stamp: Path) -> str | None:
    """The command line a step's stamp records (None: no stamp, or one from before stamps held it)."""
    try:
        return json.loads(stamp.read_text()).get("command")
    except (OSError, ValueError, AttributeError):
        return None


def read_json(path: Path) -> dict:
    return json.loads(Path(path).read_text())
