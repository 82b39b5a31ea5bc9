"""One radio-model interface and one registry of model kinds: `load_model(path or artifact) -> RadioModel`.

Every caller that predicts from a fitted `rf` artifact (predict rcs and rssi, edit, diagnose, the Python API)
loads it here and uses the RadioModel interface (radio_model_base.py): predict(tx, rx, freqs) -> path gain
[N, F] dB, materials(), save(path), geometry, settings, kind. Which implementation serves an artifact is
decided here alone, from the artifact's model attribute `model_kind` (absent on the object models rf-fit
writes from RCS or band data: those are "rcs_physical").

Kinds registered here: "rcs_physical" (the object RCS model, predict.py) and "rssi_physical" (the room model,
room_radio_model.py). A new kind is one module with a RadioModel subclass and one `register_model_kind` call
(below, or from the module that defines it); rf-fit writes its name as `model_kind`.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from rfir_core.artifacts import read_artifact
from rfir_core.errors import SchemaError

from .artifact import require_physical
from .predict import ObjectRcsModel
from .radio_model_base import FLOOR_DB, RadioModel, link_positions   # noqa: F401  (the interface, re-exported)
from .room_radio_model import RoomRadioModel

# quantities a kind predicts: "rcs" (an object's monostatic RCS, `rfir predict rcs`) or "rssi" (links in a room,
# `rfir predict rssi`); a caller that needs one names it and gets a one-line refusal for a model of the other
QUANTITIES = ("rcs", "rssi")
# model_kind values of models rfir once wrote and no longer predicts
RETIRED_KINDS = {"rssi_los_nlos": "the LoS/NLoS model (direct path + free-Gamma rendering)"}


@dataclass(frozen=True)
class ModelKind:
    """A registered kind: its name (the artifact's model_kind), loader(rf artifact, occlusion) -> RadioModel, and
    the quantity it predicts."""

    name: str
    loader: Callable[..., RadioModel]
    quantity: str


_KINDS: dict[str, ModelKind] = {}


def register_model_kind(name: str, loader: Callable[..., RadioModel], *, quantity: str) -> None:
    """Register a model kind: artifacts whose model attribute model_kind is `name` are loaded by
    loader(rf, occlusion) (a RadioModel subclass itself will do); quantity: "rcs" or "rssi"."""
    if quantity not in QUANTITIES:
        raise ValueError(f"quantity must be one of {QUANTITIES}, got {quantity!r}")
    _KINDS[name] = ModelKind(name, loader, quantity)


def model_kinds() -> dict[str, ModelKind]:
    """The registered kinds, name -> ModelKind."""
    return dict(_KINDS)


def kind_of(rf) -> str:
    """The kind name of an `rf` artifact: its model_kind, or "rcs_physical" for a physical model fitted on RCS or
    band data without one; "" when it names none rfir can tell."""
    named = str(rf.free.get("model@attrs", {}).get("model_kind", ""))
    if named:
        return named
    if str(rf.attrs.get("task", "")) in ("rcs", "wideband") and \
            str(rf.free.get("model@attrs", {}).get("family", "")) == "physical":
        return ObjectRcsModel.kind
    return ""


def quantity_of(rf) -> str | None:
    """What the model of an `rf` artifact predicts ("rcs" or "rssi"), or None for a kind rfir does not register."""
    known = _KINDS.get(kind_of(rf))
    return None if known is None else known.quantity


def _refuse(rf, kind: str, quantity: str | None) -> None:
    """SchemaError (one line naming the file and what it holds) unless `rf` holds a registered kind that predicts
    `quantity` (any, for None)."""
    task = str(rf.attrs.get("task", ""))
    known = _KINDS.get(kind)
    if quantity == "rcs" and (known is None or known.quantity != "rcs"):
        if task == "rssi" or (known is not None and known.quantity == "rssi"):
            raise SchemaError("holds an RSSI model (rf-fit on task 'rssi' measurements), not an RCS one: predict it "
                              "with `rfir predict rssi`", path=rf.path)
        require_physical(rf)
    if kind in RETIRED_KINDS:
        raise SchemaError(f"holds {RETIRED_KINDS[kind]} (model_kind {kind!r}), which rfir does not predict (RSSI is "
                          "predicted by the room model); re-run `rfir rf-fit` on its RSSI measurements", path=rf.path)
    if quantity == "rssi" and (known is None or known.quantity != "rssi"):
        if task in ("rcs", "wideband"):
            raise SchemaError(f"holds an RCS model (rf-fit on task {task!r} measurements), not an RSSI one: predict "
                              "it with `rfir predict rcs`", path=rf.path)
        raise SchemaError("not an RSSI model (fit it on task 'rssi' measurements with `rfir rf-fit`)", path=rf.path)
    if known is None:
        require_physical(rf)
        raise SchemaError(f"holds a model of kind {kind or 'unnamed'!r}, which rfir cannot predict (kinds: "
                          f"{', '.join(sorted(_KINDS))})", path=rf.path)


def require_kind(rf, quantity: str | None = None) -> str:
    """The kind name of `rf` after the checks of load_model (one-line SchemaError), without loading it."""
    kind = kind_of(rf)
    _refuse(rf, kind, quantity)
    return kind


def load_model(source, *, quantity: str | None = None, occlusion: str = "auto") -> RadioModel:
    """The RadioModel of an `rf` artifact (a path, or an artifact already read).

    quantity: "rcs" or "rssi" when the caller predicts that one (a model of the other, or of no kind rfir
    predicts, is refused with one line naming the file and what it holds); occlusion: the visibility tracer
    ("auto", "tracer" or "brute-force"; model/occlusion.py)."""
    rf = read_artifact(Path(source), "rf") if isinstance(source, (str, Path)) else source
    kind = require_kind(rf, quantity)
    return _KINDS[kind].loader(rf, occlusion)


register_model_kind(ObjectRcsModel.kind, ObjectRcsModel, quantity="rcs")
register_model_kind(RoomRadioModel.kind, RoomRadioModel, quantity="rssi")
