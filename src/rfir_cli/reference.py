"""The command reference, docs/reference/cli.md, written from the CLI itself so that it cannot drift.

    python -m rfir_cli.reference > docs/reference/cli.md

Every command and sub-command's help, as `rfir ... --help` prints it on a 100-column terminal, in the
order of `rfir --help`; tests/foundation/test_cli_reference.py fails when the committed page differs.
"""
from __future__ import annotations

import typer

from .main import app

WIDTH = 100


def _walk(command, path: list[str], parent, out: list[str]) -> None:
    """Append the help of `command` (a click command of typer's) and of every sub-command under it."""
    ctx = command.context_class(command, info_name=path[-1], parent=parent, terminal_width=WIDTH,
                                max_content_width=WIDTH)
    out += [f"{'#' * min(len(path) + 1, 4)} `{' '.join(path)}`", "", "```", command.get_help(ctx).rstrip(), "```", ""]
    if hasattr(command, "list_commands"):   # a group
        for name in command.list_commands(ctx):
            _walk(command.get_command(ctx, name), path + [name], ctx, out)


def reference() -> str:
    """The whole page (markdown)."""
    out = ["# Command reference", "",
           "Generated from the CLI by `python -m rfir_cli.reference > docs/reference/cli.md`; do not edit by hand.",
           ""]
    _walk(typer.main.get_command(app), ["rfir"], None, out)
    return "\n".join(out)


if __name__ == "__main__":
    print(reference(), end="")
