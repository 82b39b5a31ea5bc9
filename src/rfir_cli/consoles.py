"""The rich Console of the CLI's output: fitted to a terminal, never hard-wrapped when piped.

rich lays text out for an 80-column screen when it writes to a file or a pipe, so `rfir ... > log.txt`
broke messages mid-sentence and cut table cells ("wall_concre..."). Writing anywhere but a terminal,
this Console soft-wraps (one message, one line; the reader's viewer wraps it) and lays tables out at
the width their contents need.
"""
from __future__ import annotations

from rich.console import Console as RichConsole, ConsoleDimensions

# the width tables may take when not writing to a terminal: wide enough for any table's contents
PIPED_WIDTH = 10_000


class Console(RichConsole):
    """rich.console.Console that, when not writing to a terminal, neither wraps nor crops (module docstring)."""

    def _size(self) -> ConsoleDimensions:
        size = RichConsole.size.fget(self)
        if self._width is None and not self.is_terminal:
            return ConsoleDimensions(PIPED_WIDTH, size.height)
        return size

    size = property(_size, RichConsole.size.fset)

    def print(self, *objects, soft_wrap: bool | None = None, **kwargs) -> None:
        if soft_wrap is None and not self.is_terminal:
            soft_wrap = True
        super().print(*objects, soft_wrap=soft_wrap, **kwargs)
