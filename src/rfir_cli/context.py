"""What every command shares: global options, config resolution, device choice, error mapping.

Command modules stay thin: they read options, call `opts.config(section)`, hand a progress
reporter to the stage, and let `run_guarded` turn rfir errors into one line and an exit code.
"""
from __future__ import annotations

import sys
import traceback
from dataclasses import dataclass, field
from typing import Callable, TypeVar

import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress as RichProgress, TextColumn, TimeElapsedColumn, \
    TimeRemainingColumn

from rfir_core.config import resolve_config, to_toml
from .consoles import Console   # never hard-wrapped when piped (consoles.py)
from rfir_core.errors import ConfigError, RfirError
from rfir_core.progress import LineProgress

T = TypeVar("T")
console = Console()
err_console = Console(stderr=True)


@dataclass
class GlobalOptions:
    """Options given before the command name (`rfir --set a.b=1 simulate ...`)."""

    config_file: str | None = None
    overrides: list[str] = field(default_factory=list)
    recipe: str | None = None
    device: str = "auto"
    seed: int = 0
    verbosity: int = 0
    force: bool = False   # --force: an output may replace an existing file of another kind

    def config(self) -> dict:
        """The resolved config (all sections)."""
        return resolve_config(self.config_file, self.overrides, self.recipe)

    def config_toml(self) -> str:
        return to_toml(self.config())

    def torch_device(self) -> str:
        """'cpu' or 'cuda', refusing cuda where there is none."""
        import torch

        if self.device == "auto":
            return "cuda" if torch.cuda.is_available() else "cpu"
        if self.device == "cuda" and not torch.cuda.is_available():
            raise ConfigError("--device cuda asked for, but this torch has no CUDA device (use --device cpu or auto)")
        if self.device not in ("cpu", "cuda"):
            raise ConfigError(f"--device {self.device!r}: expected auto, cpu or cuda")
        return self.device


def options(ctx: typer.Context) -> GlobalOptions:
    """The GlobalOptions stored by the app callback (defaults when called without one)."""
    root = ctx.find_root()
    if not isinstance(root.obj, GlobalOptions):
        root.obj = GlobalOptions()
    return root.obj


class RichReporter:
    """The CLI's `rfir_core.progress.Progress`: rich bars on a terminal, plain lines otherwise.

    Quiet when verbosity < 0. Without a terminal (output piped to a log), a rich bar prints
    nothing until it ends, so a long fit looks hung; there `LineProgress` prints step, loss and
    ETA at least every `line_interval_s` instead.
    """

    def __init__(self, verbosity: int = 0, line_interval_s: float = 30.0):
        self.verbosity = verbosity
        self._lines = None if err_console.is_terminal or verbosity < 0 else LineProgress(interval_s=line_interval_s)
        self._bars = RichProgress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                                  TimeElapsedColumn(), TimeRemainingColumn(), TextColumn("{task.fields[loss]}"),
                                  console=err_console, disable=verbosity < 0 or self._lines is not None,
                                  transient=False)

    def __enter__(self):
        (self._lines or self._bars).__enter__()
        return self

    def __exit__(self, *exc):
        return (self._lines or self._bars).__exit__(*exc)

    def task(self, description: str, total: float | None = None):
        if self._lines is not None:
            return self._lines.task(description, total)
        return _RichTask(self._bars, description, total)

    def log(self, message: str) -> None:
        """Stage messages are plain text: no markup or emoji codes ("[m]", ":A:") to swallow."""
        if self.verbosity < 0:
            return
        if self._lines is not None:
            self._lines.log(message)
        else:
            self._bars.console.print(message, markup=False, emoji=False, highlight=False, soft_wrap=True)


class _RichTask:
    def __init__(self, bars: RichProgress, description: str, total: float | None):
        self._bars, self._description, self._total = bars, description, total

    def __enter__(self):
        self._id = self._bars.add_task(self._description, total=self._total, loss="")
        return self

    def __exit__(self, *exc):
        task = self._bars.tasks[self._bars.task_ids.index(self._id)]
        if task.total is not None and not exc[0]:
            self._bars.update(self._id, completed=task.total)
        return False

    def advance(self, amount: float = 1) -> None:
        self._bars.advance(self._id, amount)

    def update(self, *, total: float | None = None, description: str | None = None,
               loss: float | None = None) -> None:
        fields = {} if loss is None else {"loss": f"loss {loss:.4g}"}
        self._bars.update(self._id, total=total, description=description, **fields)


def run_guarded(ctx: typer.Context, work: Callable[[], T]) -> T:
    """Run `work`, mapping RfirError to one red line and its exit code; tracebacks only with -v."""
    verbosity = options(ctx).verbosity
    try:
        return work()
    except RfirError as exc:
        if verbosity > 0:
            traceback.print_exc()
        # escaped: a message quotes file contents, which may look like markup ("[/]")
        err_console.print(f"[red]error:[/red] {escape(str(exc))}", markup=True, emoji=False, highlight=False, soft_wrap=True)
        raise typer.Exit(exc.exit_code) from None
    except KeyboardInterrupt:
        err_console.print("[red]interrupted[/red]")
        raise typer.Exit(130) from None
    except typer.Exit:
        raise
    except Exception as exc:  # noqa: BLE001 - the last line of defence: no traceback unless -v
        if verbosity > 0:
            traceback.print_exc()
        err_console.print(f"[red]internal error:[/red] {type(exc).__name__}: {escape(str(exc))} "
                          "(run with -v for the traceback)", emoji=False,
                          soft_wrap=True, highlight=False)
        raise typer.Exit(70) from None


def fail(message: str, code: int = 2) -> None:
    """Print one error line and exit (for option problems detected in a command module)."""
    err_console.print(f"[red]error:[/red] {message}", soft_wrap=True, highlight=False)
    sys.exit(code)


def comma_numbers(text: str | None, what: str, n: int) -> list[float] | None:
    """Option text "A,B,C" -> [n] floats, None when not given; a ConfigError naming the option otherwise."""
    from rfir_core.errors import ConfigError

    if text is None:
        return None
    try:
        vals = [float(x) for x in text.split(",")]
    except ValueError:
        vals = []
    if len(vals) != n:
        raise ConfigError(f"{what} {text!r}: expected {n} comma-separated numbers")
    return vals
