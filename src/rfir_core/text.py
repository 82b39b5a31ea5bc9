"""Small wording helpers shared by the commands and the stages' messages."""
from __future__ import annotations

import math


def plural(n: int, word: str, many: str | None = None) -> str:
    """'1 frequency', '2 frequencies', '0 links': the count and the word in agreement with it.

    many: the plural form where adding "s" (or "ies" after a consonant and y, "es" after s, x, ch or
    sh) is wrong."""
    if n == 1:
        return f"{n} {word}"
    if many is None:
        if word.endswith("y") and word[-2:-1] not in ("a", "e", "i", "o", "u", ""):
            many = word[:-1] + "ies"
        elif word.endswith(("s", "x", "ch", "sh")):
            many = word + "es"
        else:
            many = word + "s"
    return f"{n} {many}"


def standard_errors(value: float, digits: int = 1, limit: float = 1e6) -> str:
    """A number of standard errors for a message: '+1.3 SE', or 'not determined by the links' where the
    standard error is zero or the ratio is not finite or beyond `limit` (every link fitted exactly)."""
    if not math.isfinite(value) or abs(value) > limit:
        return "not determined by the links"
    return f"{value:+.{digits}f} SE"
