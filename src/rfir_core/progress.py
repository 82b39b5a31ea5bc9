"""Progress reporting that stages use without knowing about the terminal.

Stages take a `Progress` and call `with progress.task("label", total=n) as task: task.advance()`,
and may report the latest loss with `task.update(loss=value)`. The CLI passes a rich bar on a
terminal and `LineProgress` otherwise (a log file or a pipe, where a bar shows nothing until the
end); tests and library users get `NullProgress`.
"""
from __future__ import annotations

import sys
import threading
import time
from contextlib import contextmanager
from typing import Callable, Iterator, Protocol, TextIO


class TaskHandle(Protocol):
    def advance(self, amount: float = 1) -> None: ...

    def update(self, *, total: float | None = None, description: str | None = None,
               loss: float | None = None) -> None: ...


class Progress(Protocol):
    def task(self, description: str, total: float | None = None): ...

    def log(self, message: str) -> None: ...


class _NullTask:
    def advance(self, amount: float = 1) -> None:
        pass

    def update(self, *, total: float | None = None, description: str | None = None,
               loss: float | None = None) -> None:
        pass


class NullProgress:
    """Reports nothing; collects log messages in `.messages` (handy in tests)."""

    def __init__(self) -> None:
        self.messages: list[str] = []

    @contextmanager
    def task(self, description: str, total: float | None = None) -> Iterator[_NullTask]:
        yield _NullTask()

    def log(self, message: str) -> None:
        self.messages.append(message)


def format_duration(seconds: float) -> str:
    """'45s', '12m03s', '2h05m': short enough for a log line, exact enough to plan by."""
    s = max(0, int(round(seconds)))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{s % 3600 // 60:02d}m"


class LineProgress:
    """Progress as plain lines, for output that is not a terminal (a log file, a pipe, CI).

    Each open task prints `description: step/total (pct), loss L, elapsed E, ETA T` when it
    advances and `interval_s` has passed since its last line (`update` only records, so a loss
    reported before `advance` shows on that step's line), and once when it ends. A heartbeat
    thread (started by `with`) prints the same for tasks whose step itself takes longer than
    the interval, so a log never stays silent for more than about `interval_s` while work runs.
    No line at the start (short tasks print only their end line) and none when a task ends in
    an error (the error line says where it stopped). The ETA assumes the rate so far holds.
    `clock` and `heartbeat=False` let tests drive time by hand.
    """

    def __init__(self, stream: TextIO | None = None, interval_s: float = 30.0,
                 clock: Callable[[], float] = time.monotonic, heartbeat: bool = True):
        self._stream, self.interval_s, self.clock, self._heartbeat = stream, float(interval_s), clock, heartbeat
        self._open: list[_LineTask] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def __enter__(self):
        if self._heartbeat:
            self._stop.clear()
            self._thread = threading.Thread(target=self._beat, name="rfir-progress", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        return False

    def _beat(self) -> None:
        while not self._stop.wait(min(self.interval_s, 5.0)):
            self.tick()

    def tick(self) -> None:
        """Print a line for every open task that has been quiet for `interval_s` (the heartbeat)."""
        for task in list(self._open):
            task.maybe_print()

    def write(self, line: str) -> None:
        stream = self._stream if self._stream is not None else sys.stderr   # looked up late: redirections apply
        with self._lock:
            stream.write(line + "\n")
            stream.flush()

    def task(self, description: str, total: float | None = None) -> "_LineTask":
        return _LineTask(self, description, total)

    def log(self, message: str) -> None:
        self.write(message)


class _LineTask:
    def __init__(self, owner: LineProgress, description: str, total: float | None):
        self._owner, self.description, self.total = owner, description, total
        self.completed, self.loss = 0.0, None
        self._start = self._last = 0.0

    def __enter__(self):
        self._start = self._last = self._owner.clock()
        self._owner._open.append(self)
        return self

    def __exit__(self, *exc):
        self._owner._open.remove(self)
        if exc[0] is None:
            if self.total is not None:
                self.completed = self.total
            self._owner.write(self.line(done=True))
        return False

    def advance(self, amount: float = 1) -> None:
        self.completed += amount
        self.maybe_print()

    def update(self, *, total: float | None = None, description: str | None = None,
               loss: float | None = None) -> None:
        if total is not None:
            self.total = total
        if description is not None:
            self.description = description
        if loss is not None:
            self.loss = float(loss)

    def maybe_print(self) -> None:
        now = self._owner.clock()
        if now - self._last >= self._owner.interval_s:
            self._last = now
            self._owner.write(self.line())

    def line(self, done: bool = False) -> str:
        elapsed = self._owner.clock() - self._start
        n = f"{self.completed:g}"
        parts = [f"{self.description}: {n}/{self.total:g} ({100 * self.completed / self.total:.0f}%)"
                 if self.total else f"{self.description}: {n} steps"]
        if self.loss is not None:
            parts.append(f"loss {self.loss:.4g}")
        parts.append(f"elapsed {format_duration(elapsed)}")
        if done:
            parts.append("done")
        elif self.total and self.completed > 0:
            parts.append(f"ETA {format_duration(elapsed / self.completed * max(self.total - self.completed, 0))}")
        else:
            parts.append("ETA unknown")
        return ", ".join(parts)
