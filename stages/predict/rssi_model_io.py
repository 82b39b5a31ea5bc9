"""Load the fitted RSSI model of an `rf` artifact: the physical room model (rfir_stages.model.room).

`load_predictor(rf)` returns a `RoomPredictor` (geom, provider, freq_hz, path_gain_db(tx, rx),
memory_estimate_bytes) for an artifact rf-fit wrote from RSSI measurements (model_kind
"rssi_physical"); any other artifact is refused with one line naming the file and what it holds.
"""
from __future__ import annotations

from rfir_core.errors import SchemaError

ROOM_KIND = "rssi_physical"
OLD_KINDS = {"rssi_los_nlos": "the LoS/NLoS model (direct path + free-Gamma rendering)"}


def require_room_model(rf) -> None:
    """SchemaError (one line naming the file and what it holds) unless `rf` holds the room model."""
    kind = str(rf.free.get("model@attrs", {}).get("model_kind", ""))
    if kind in OLD_KINDS:
        raise SchemaError(f"holds {OLD_KINDS[kind]} (model_kind {kind!r}), which rfir does not predict (RSSI is "
                          "predicted by the room model); re-run `rfir rf-fit` on its RSSI measurements", path=rf.path)
    task = str(rf.attrs.get("task", ""))
    if kind != ROOM_KIND and task in ("rcs", "wideband"):
        raise SchemaError(f"holds an RCS model (rf-fit on task {task!r} measurements), not an RSSI one: predict it "
                          "with `rfir predict rcs`", path=rf.path)
    if kind != ROOM_KIND:
        raise SchemaError("not an RSSI model (fit it on task 'rssi' measurements with `rfir rf-fit`)", path=rf.path)


def load_predictor(rf, occlusion: str = "auto"):
    """The RoomPredictor of an RSSI `rf` artifact; SchemaError (one line) for anything else."""
    require_room_model(rf)
    from rfir_stages.model.room import RoomPredictor

    return RoomPredictor(rf, occlusion)
