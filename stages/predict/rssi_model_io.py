"""The room model of an `rf` artifact, through the one model registry (rfir_stages.model.radio_model).

`require_room_model(rf)` refuses, with one line naming the file and what it holds, an artifact that is not an
RSSI (room) model; `load_predictor(rf)` returns the room's RoomPredictor (geom, provider, freq_hz,
path_gain_db(tx, rx), memory_estimate_bytes) for code that works on the room's internals (benchmarks, the edit
stage's map picture). Prediction itself goes through `load_model(rf, quantity="rssi").predict(...)`.
"""
from __future__ import annotations

from rfir_stages.model.radio_model import load_model, require_kind


def require_room_model(rf) -> None:
    """SchemaError (one line naming the file and what it holds) unless `rf` holds an RSSI model."""
    require_kind(rf, "rssi")


def load_predictor(rf, occlusion: str = "auto"):
    """The RoomPredictor of an RSSI `rf` artifact; SchemaError (one line) for anything else."""
    return load_model(rf, quantity="rssi", occlusion=occlusion).predictor
