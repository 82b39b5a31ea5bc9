"""What the running command read and wrote: no output over a file it read as an input (artifacts.py's
check_output and write_artifact ask here; read_artifact and Provenance.add_input note inputs, write_artifact notes
outputs). `begin_command` .. `end_command` (set up by the CLI's callback) bound a command; library calls outside a
command are not guarded. Kept apart from artifacts.py so that provenance.py can note inputs without importing it.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class _OutputGuard:
    """What the running command read and wrote (resolved paths) and whether --force was given."""

    active: bool = False
    force: bool = False
    inputs: set = field(default_factory=set)
    written: set = field(default_factory=set)


GUARD = _OutputGuard()   # the running command's (read it as output_guard.GUARD: begin_command replaces it)


def _key(path: str | Path) -> str:
    return os.path.realpath(os.fspath(path))


def begin_command(force: bool = False) -> None:
    """Start a command: forget earlier inputs and outputs; force: --force was given (an existing file of
    another kind may be replaced; an input of the command never is)."""
    global GUARD
    GUARD = _OutputGuard(active=True, force=bool(force))


def end_command() -> None:
    """End the command started by begin_command (library calls outside a command are not guarded)."""
    global GUARD
    GUARD = _OutputGuard()


def note_input(path: str | Path) -> None:
    """Record that the running command read `path` (no effect outside a command, or for its own outputs)."""
    if GUARD.active and path is not None:
        key = _key(path)
        if key not in GUARD.written:
            GUARD.inputs.add(key)


def note_output(path: str | Path) -> None:
    """Record a file the running command wrote (rewriting it later in the same command is allowed)."""
    if GUARD.active:
        key = _key(path)
        GUARD.written.add(key)
        GUARD.inputs.discard(key)
