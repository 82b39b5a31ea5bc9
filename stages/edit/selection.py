"""Selections of Gaussians: `box:`, `obox:`, `sphere:`, `label:` and `all`, parsed from one string.

Syntax (metres and degrees, world frame):
  box:XMIN,YMIN,ZMIN,XMAX,YMAX,ZMAX         axis-aligned box (inclusive)
  obox:CX,CY,CZ,HX,HY,HZ[,YAW[,PITCH[,ROLL]]] oriented box: centre, half extents, z-y-x Euler angles in degrees
  sphere:CX,CY,CZ,R                         ball of radius R
  label:NAME                                object label by name (shell patterns such as chair_* allowed) or integer id
  all                                       every Gaussian
A Gaussian is selected when its centre (gaussians/means) is inside.
"""
from __future__ import annotations

import fnmatch
import math
from dataclasses import dataclass

import numpy as np

from rfir_core.errors import ConfigError

_ARITY = {"box": (6, 6), "obox": (6, 9), "sphere": (4, 4)}


@dataclass(frozen=True)
class Selection:
    """A parsed selection. kind: box|obox|sphere|label|all; numbers: its parameters; label: name or id text."""

    kind: str
    numbers: tuple = ()
    label: str = ""
    text: str = ""

    def mask(self, means_m: np.ndarray, labels: np.ndarray | None = None, label_names=None) -> np.ndarray:
        """[G] bool: which Gaussians (centres means_m [G, 3] m) are selected."""
        p = np.asarray(means_m, np.float64)
        if self.kind == "all":
            return np.ones(len(p), bool)
        if self.kind == "box":
            lo, hi = np.asarray(self.numbers[:3]), np.asarray(self.numbers[3:])
            return np.all((p >= lo) & (p <= hi), axis=1)
        if self.kind == "sphere":
            c, r = np.asarray(self.numbers[:3]), self.numbers[3]
            return np.sum((p - c) ** 2, axis=1) <= r * r
        if self.kind == "obox":
            c, half = np.asarray(self.numbers[:3]), np.asarray(self.numbers[3:6])
            angles = list(self.numbers[6:]) + [0.0] * (9 - len(self.numbers))
            local = (p - c) @ euler_zyx_deg(*angles)  # world -> box axes: R^T (p - c), row form
            return np.all(np.abs(local) <= half, axis=1)
        return self._label_mask(len(p), labels, label_names)

    def _label_mask(self, g: int, labels, label_names) -> np.ndarray:
        if labels is None:
            raise ConfigError(f"--select {self.text}: the artifact has no gaussians/labels (label a box first: --op label:NAME)")
        labels = np.asarray(labels)
        if self.label.lstrip("-").isdigit():
            return labels == int(self.label)
        names = [str(n) for n in (label_names if label_names is not None else [])]
        ids = [i for i, n in enumerate(names) if fnmatch.fnmatchcase(n, self.label)]
        if not ids:
            known = ", ".join(names[:12]) or "none"
            raise ConfigError(f"--select {self.text}: no label named {self.label!r} (labels: {known})")
        return np.isin(labels, ids)


def euler_zyx_deg(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """[3, 3] rotation Rz(yaw) Ry(pitch) Rx(roll), angles in degrees; columns are the box axes in the world."""
    a, b, c = (math.radians(v) for v in (yaw, pitch, roll))
    rz = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    rx = np.array([[1, 0, 0], [0, math.cos(c), -math.sin(c)], [0, math.sin(c), math.cos(c)]])
    return rz @ ry @ rx


def parse_numbers(text: str, where: str) -> tuple:
    """'1,2.5,-3' -> (1.0, 2.5, -3.0); ConfigError naming `where` on a bad or non-finite number."""
    try:
        values = tuple(float(x) for x in text.split(",")) if text.strip() else ()
    except ValueError:
        raise ConfigError(f"{where}: expected comma-separated numbers, got {text!r}") from None
    if not all(math.isfinite(v) for v in values):
        raise ConfigError(f"{where}: numbers must be finite, got {text!r}")
    return values


def parse_selection(text: str) -> Selection:
    """Parse one selection string (module docstring); ConfigError naming --select on any mistake."""
    text = text.strip()
    kind, _, rest = text.partition(":")
    kind = kind.strip().lower()
    where = f"--select {text!r}"
    if kind == "all" and not rest:
        return Selection("all", text=text)
    if kind == "label":
        if not rest.strip():
            raise ConfigError(f"{where}: expected label:NAME")
        return Selection("label", label=rest.strip(), text=text)
    if kind not in _ARITY:
        raise ConfigError(f"{where}: unknown selection {kind!r} (expected box, obox, sphere, label or all)")
    numbers = parse_numbers(rest, where)
    lo, hi = _ARITY[kind]
    if not lo <= len(numbers) <= hi:
        want = str(lo) if lo == hi else f"{lo} to {hi}"
        raise ConfigError(f"{where}: {kind} takes {want} numbers, got {len(numbers)}")
    if kind == "box" and any(numbers[i] > numbers[i + 3] for i in range(3)):
        raise ConfigError(f"{where}: box minimum exceeds maximum")
    if kind == "sphere" and numbers[3] <= 0 or kind == "obox" and min(numbers[3:6]) <= 0:
        raise ConfigError(f"{where}: radius and half extents must be positive")
    return Selection(kind, numbers, text=text)
