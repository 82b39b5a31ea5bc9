"""Edit lists: from `--select`/`--op` pairs or a TOML edit script.

Script format (docs/guide/edit.md):
    [[edit]]
    select = "sphere:0,0,0,0.2"
    op = "translate:1,0,0"
    allow_empty = false   # optional
    note = "move the chair"  # optional
Unknown keys anywhere are refused, naming the key.
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

from rfir_core.errors import ConfigError, InputFileError

from .operations import Operation, parse_operation
from .selection import Selection, parse_selection

_EDIT_KEYS = {"select", "op", "allow_empty", "note"}


@dataclass(frozen=True)
class Edit:
    """One edit: a selection, an operation (None: only list the selection), and whether empty is allowed."""

    select: Selection
    op: Operation | None
    allow_empty: bool = False
    note: str = ""


def edits_from_options(selects: list[str], ops: list[str], allow_empty: bool = False) -> list[Edit]:
    """Pair --select and --op in order. A lone --select with no --op only lists (for --dry-run)."""
    if ops and len(selects) != len(ops):
        raise ConfigError(f"--select given {len(selects)} times but --op {len(ops)} times; give one --select per --op")
    sel = [parse_selection(s) for s in selects]
    return [Edit(s, parse_operation(o) if ops else None, allow_empty) for s, o in zip(sel, ops or [None] * len(sel))]


def read_script(path: str | Path, allow_empty: bool = False) -> list[Edit]:
    """Parse a TOML edit script; ConfigError naming the file and the key on any mistake."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise InputFileError("edit script not found", path=path) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise InputFileError(f"cannot read edit script: {exc}", path=path) from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    for key in doc:
        if key != "edit":
            raise ConfigError(f"{path}: unknown key {key!r} (expected [[edit]] tables)")
    tables = doc.get("edit", [])
    if not isinstance(tables, list) or not tables:
        raise ConfigError(f"{path}: no [[edit]] tables")
    edits = []
    for i, table in enumerate(tables, 1):
        for key in table:
            if key not in _EDIT_KEYS:
                raise ConfigError(f"{path}: edit {i}: unknown key {key!r} (expected {', '.join(sorted(_EDIT_KEYS))})")
        for key in ("select", "op"):
            if not isinstance(table.get(key), str):
                raise ConfigError(f"{path}: edit {i}: '{key}' is missing or not a string")
        flag = table.get("allow_empty", allow_empty)
        if not isinstance(flag, bool):
            raise ConfigError(f"{path}: edit {i}: 'allow_empty' must be true or false")
        try:
            edits.append(Edit(parse_selection(table["select"]), parse_operation(table["op"]), flag,
                              str(table.get("note", ""))))
        except ConfigError as exc:
            raise ConfigError(f"{path}: edit {i}: {exc}") from None
    return edits
