"""Operations on a selection of Gaussians, applied to every per-Gaussian array of an `rf` artifact.

Syntax (metres, degrees):
  translate:DX,DY,DZ                 move centres
  rotate:AX,AY,AZ,DEG[,PX,PY,PZ]     rotate by DEG about axis (AX,AY,AZ) through pivot P (default: the
                                     selection's centroid); means, quaternions and normals turn together
  delete                             remove the Gaussians
  duplicate:DX,DY,DZ                 append copies moved by (DX,DY,DZ)
  label:NAME                         give the selection the object label NAME (for later label:NAME selections)
  material:NAME                      the selection becomes the ITU-R P.2040 material NAME (metal, glass,
                                     concrete, ...) at the model's frequency, keeping its thickness and
                                     scattering coefficient
The fitted model predicts from its materials (material/*), not from per-Gaussian radio attributes, so
there is no operation that sets or scales rf/* values: `set:` and `scale:` are refused in one line that
points to material:NAME.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from rfir_core.errors import ConfigError

from .selection import parse_numbers

# Operations of earlier artifact families that changed per-Gaussian rf/* attributes; the model reads none.
RETIRED_KINDS = ("set", "scale")


@dataclass(frozen=True)
class Operation:
    """A parsed operation. kind: translate|rotate|delete|duplicate|label|material."""

    kind: str
    numbers: tuple = ()
    name: str = ""
    text: str = ""


@dataclass
class EditScene:
    """The per-Gaussian state being edited.

    arrays: "group/name" -> array with first dimension G (gaussians/*, rf/* and free-group datasets).
    label_names: names of the label ids. origin [G]: index of each Gaussian in the input (copies keep
    their source's); touched [G]: changed by some edit.
    """

    arrays: dict
    label_names: list = field(default_factory=list)
    origin: np.ndarray = None
    touched: np.ndarray = None
    num_materials: int = 0                               # materials of a physical model (material/*)
    new_materials: list = field(default_factory=list)   # (ITU name, material it replaces) appended by edits

    def __post_init__(self):
        g = self.count
        self.origin = np.arange(g) if self.origin is None else self.origin
        self.touched = np.zeros(g, bool) if self.touched is None else self.touched

    @property
    def count(self) -> int:
        return len(self.arrays["gaussians/means"])

    def take(self, index: np.ndarray) -> None:
        """Keep (and reorder / repeat) Gaussians by integer index [G'] in every per-Gaussian array."""
        self.arrays = {k: v[index] for k, v in self.arrays.items()}
        self.origin, self.touched = self.origin[index], self.touched[index]


def parse_operation(text: str) -> Operation:
    """Parse one operation string (module docstring); ConfigError naming --op on any mistake."""
    text = text.strip()
    kind, _, rest = text.partition(":")
    kind, where = kind.strip().lower(), f"--op {text!r}"
    if kind == "delete":
        if rest.strip():
            raise ConfigError(f"{where}: delete takes no arguments")
        return Operation("delete", text=text)
    if kind == "label":
        if not rest.strip():
            raise ConfigError(f"{where}: expected label:NAME")
        return Operation("label", name=rest.strip(), text=text)
    if kind == "material":
        from rfir_core.physics.materials import material_key
        try:
            return Operation("material", name=material_key(rest), text=text)
        except ValueError as e:
            raise ConfigError(f"{where}: {e}") from None
    if kind in RETIRED_KINDS:
        raise ConfigError(f"{where}: {kind}: is not an operation (the model predicts from its materials, not from "
                          "per-Gaussian rf/* attributes); give the selection a material with material:NAME "
                          "(e.g. material:metal)")
    arity = {"translate": (3,), "duplicate": (3,), "rotate": (4, 7)}
    if kind not in arity:
        raise ConfigError(f"{where}: unknown operation {kind!r} (expected translate, rotate, delete, duplicate, label "
                          "or material)")
    numbers = parse_numbers(rest, where)
    if len(numbers) not in arity[kind]:
        raise ConfigError(f"{where}: {kind} takes {' or '.join(map(str, arity[kind]))} numbers, got {len(numbers)}")
    if kind == "rotate" and np.linalg.norm(numbers[:3]) == 0:
        raise ConfigError(f"{where}: the rotation axis is zero")
    return Operation(kind, numbers, text=text)


def axis_angle_quaternion(axis, angle_deg: float) -> np.ndarray:
    """[4] unit quaternion (w, x, y, z) of a rotation by angle_deg about axis [3]."""
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    half = math.radians(angle_deg) / 2
    return np.concatenate([[math.cos(half)], math.sin(half) * axis])


def quat_multiply(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product p * q of (w, x, y, z) quaternions, broadcast over leading dims."""
    pw, px, py, pz = np.moveaxis(np.asarray(p, np.float64), -1, 0)
    qw, qx, qy, qz = np.moveaxis(np.asarray(q, np.float64), -1, 0)
    return np.stack([pw * qw - px * qx - py * qy - pz * qz, pw * qx + px * qw + py * qz - pz * qy,
                     pw * qy - px * qz + py * qw + pz * qx, pw * qz + px * qy - py * qx + pz * qw], -1)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """[..., 3, 3] rotation matrices of (w, x, y, z) quaternions [..., 4] (normalised first)."""
    q = np.asarray(q, np.float64)
    w, x, y, z = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                     np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                     np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def covariances(log_scales: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """[G, 3, 3] covariances R diag(exp(2 log_scales)) R^T in m^2 from log_scales [G, 3] and quaternions [G, 4]."""
    r = quat_to_matrix(rotations)
    return r @ (np.exp(2 * np.asarray(log_scales))[:, :, None] * np.swapaxes(r, -1, -2))


def _fmt(values) -> str:
    return ",".join(repr(float(v)) for v in values)  # shortest text that reads back exactly


def apply(scene: EditScene, mask: np.ndarray, op: Operation) -> dict:
    """Apply op to the Gaussians where mask [G] is true, in place. Returns the history record:
    {"op": resolved text, "inverse": text or None, "count": n, "warnings": [...]}."""
    idx = np.flatnonzero(mask)
    rec = {"op": op.text, "inverse": None, "count": int(idx.size), "warnings": []}
    a = scene.arrays
    if op.kind == "translate":
        a["gaussians/means"][idx] += np.asarray(op.numbers)
        rec["inverse"] = "translate:" + _fmt(-np.asarray(op.numbers))
    elif op.kind == "rotate":
        pivot = np.asarray(op.numbers[4:] if len(op.numbers) == 7 else
                           (a["gaussians/means"][idx].mean(0) if idx.size else np.zeros(3)))
        q = axis_angle_quaternion(op.numbers[:3], op.numbers[3])
        rot = quat_to_matrix(q)
        a["gaussians/means"][idx] = (a["gaussians/means"][idx] - pivot) @ rot.T + pivot
        a["gaussians/normals"][idx] = a["gaussians/normals"][idx] @ rot.T
        composed = quat_multiply(q, a["gaussians/rotations"][idx])
        a["gaussians/rotations"][idx] = composed / np.linalg.norm(composed, axis=-1, keepdims=True)
        rec["op"] = f"rotate:{_fmt(op.numbers[:3])},{_fmt([op.numbers[3]])},{_fmt(pivot)}"
        rec["inverse"] = f"rotate:{_fmt(op.numbers[:3])},{_fmt([-op.numbers[3]])},{_fmt(pivot)}"
    elif op.kind == "delete":
        scene.take(np.flatnonzero(~mask))
        return rec
    elif op.kind == "duplicate":
        g = scene.count
        scene.take(np.concatenate([np.arange(g), idx]))
        scene.arrays["gaussians/means"][g:] += np.asarray(op.numbers)
        scene.touched[g:] = True
        return rec
    elif op.kind == "material":
        if "material/index" not in a:
            raise ConfigError(f"--op {op.text!r}: re-materialing needs the model's material/index dataset, "
                              "which this artifact lacks")
        if idx.size:
            was = int(np.bincount(a["material/index"][idx]).argmax())
            scene.new_materials.append((op.name, was))
            a["material/index"][idx] = scene.num_materials + len(scene.new_materials) - 1
    elif op.kind == "label":
        if "gaussians/labels" not in a:
            a["gaussians/labels"] = np.full(scene.count, -1, np.int64)
        if op.name not in scene.label_names:
            scene.label_names.append(op.name)
        a["gaussians/labels"][idx] = scene.label_names.index(op.name)
        return rec
    scene.touched[idx] = True
    return rec
