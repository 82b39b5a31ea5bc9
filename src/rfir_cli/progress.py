"""Progress reporting that stages use without knowing about the terminal.

Stages take a `Progress` and call `with progress.task("label", total=n) as task: task.advance()`.
The CLI passes a rich-backed reporter; tests and library users get `NullProgress`.
"""
from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator, Protocol


class TaskHandle(Protocol):
    def advance(self, amount: float = 1) -> None: ...

    def update(self, *, total: float | None = None, description: str | None = None) -> None: ...


class Progress(Protocol):
    def task(self, description: str, total: float | None = None): ...

    def log(self, message: str) -> None: ...


class _NullTask:
    def advance(self, amount: float = 1) -> None:
        pass

    def update(self, *, total: float | None = None, description: str | None = None) -> None:
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
