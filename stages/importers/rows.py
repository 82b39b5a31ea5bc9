"""Row-level problems, collected so one error can name every bad row (up to a limit)."""
from __future__ import annotations

from dataclasses import dataclass, field

from rfir_core.errors import InputFileError


@dataclass
class RowProblems:
    """Accumulates 'line N: ...' messages for one input file."""

    path: str
    shown: int = 6
    problems: list[str] = field(default_factory=list)
    hints: list[str] = field(default_factory=list)

    def add(self, message: str) -> None:
        self.problems.append(message)

    def hint(self, message: str) -> None:
        """A remedy printed once after the problems (e.g. the flag that fixes them)."""
        if message not in self.hints:
            self.hints.append(message)

    def raise_if_any(self) -> None:
        """Raise one InputFileError naming the file, the count and the first few problems."""
        if not self.problems:
            return
        head = "; ".join(self.problems[: self.shown])
        more = f"; ... and {len(self.problems) - self.shown} more" if len(self.problems) > self.shown else ""
        noun = "problem" if len(self.problems) == 1 else "problems"
        hint = "".join(f"; {h}" for h in self.hints)
        raise InputFileError(f"{len(self.problems)} {noun}, nothing written: {head}{more}{hint}", path=self.path)


def check_metres(positions, what: str, problems: RowProblems, max_abs_m: float = 1000.0) -> None:
    """Flag coordinates that are clearly not metres (e.g. millimetres) with a hint."""
    import numpy as np

    if positions.size and np.nanmax(np.abs(positions)) > max_abs_m:
        worst = float(np.nanmax(np.abs(positions)))
        problems.add(f"{what} reach {worst:g}, which looks like millimetres or centimetres: rfir expects metres "
                     f"(pass --position-unit mm or --position-unit cm, or rescale the file)")
