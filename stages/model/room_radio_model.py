"""The room model kind: received power in a room from the paths through and off its surfaces plus diffuse power
(docs/physics.md section 8.10; model/room.py), for an `rf` artifact rf-fit wrote from RSSI measurements.

`RoomRadioModel` (a radio_model_base.RadioModel) wraps room.RoomPredictor, which loads the fitted room once
(patches, diffuse cells, the tracer, the device gains) and sums each link's paths as the model was fitted
(room.band). It predicts at any frequency inside its material laws' range (RoomPredictor.predict_db: the paths
are traced once per block of links, the frequency applied at evaluation); by default at the one it was fitted at.
The residual terms rf-fit chose (device patterns, clutter field, kriging; residual_terms.py) are added in dB at
every frequency; predict_with_physics_only gives the prediction without them.
"""
from __future__ import annotations

import numpy as np

from rfir_core.errors import StageError

from .radio_model_base import FLOOR_DB, RadioModel
from .residual_terms import ResidualTerms
from .room import RoomPredictor


class RoomRadioModel(RadioModel):
    """The physical room model of an RSSI fit; settings: room.RoomSettings; predictor: the RoomPredictor it
    wraps (patches, diffuse cells, device gains), for room-specific questions (device_ends_matched)."""

    kind = "rssi_physical"
    BYTES_PER_LINK = RoomPredictor.BYTES_PER_LINK

    def __init__(self, rf, occlusion: str = "auto"):
        super().__init__(rf, occlusion)
        self.predictor = RoomPredictor(rf, occlusion)
        self.settings = self.predictor.room.settings
        self.geometry = self.predictor.geom
        # the residual terms in dB on top of the physics (None: a model fitted without them)
        self.residual_terms = ResidualTerms.from_model(rf.free.get("model", {}), rf.free.get("model@attrs", {}))

    @property
    def provider(self):
        """The occlusion provider the room traces with."""
        return self.predictor.provider

    def memory_estimate_bytes(self, num_links: int, chunk_links: int) -> int:
        return self.predictor.memory_estimate_bytes(num_links, chunk_links)

    def training_split(self, meas) -> np.ndarray | None:
        """0 training, 1 test per measured row as the fit split them: the transmitters it held out, or the file's
        split column; None when the file lacks what that needs."""
        protocol = str(self.artifact.free.get("training@attrs", {}).get("split", "file"))
        if protocol == "holdout_tx":
            held = np.asarray(self.artifact.free.get("training", {}).get("holdout_tx_ids", []), np.int64)
            tx_id = meas.get("tx_id")
            if tx_id is None or held.size == 0:
                return None
            return np.isin(np.asarray(tx_id), held).astype(np.int64)
        return super().training_split(meas)

    def held_out_rows(self, meas) -> tuple[np.ndarray, np.ndarray, str]:
        """As RadioModel.held_out_rows; a fit that held transmitters out names them."""
        if str(self.artifact.free.get("training@attrs", {}).get("split", "file")) != "holdout_tx":
            return super().held_out_rows(meas)
        split = self.training_split(meas)
        if split is None:
            raise StageError("the model held transmitters out, but the measurements have no tx_id", path=meas.path)
        held = np.asarray(self.artifact.free.get("training", {}).get("holdout_tx_ids", []), np.int64)
        return np.flatnonzero(split == 1), np.flatnonzero(split == 0), f"transmitters {held.tolist()} held out"

    def _path_gain_db(self, tx, rx, freqs, progress, advance, chunk_links, physics_only, axes=None):
        chunk_links = int(chunk_links or 512)
        if advance is not None:
            out = self.predictor.predict_db(tx, rx, freqs, chunk_links, _Advance(advance), axes)
        else:
            with progress.task("predict (room)", total=len(tx)) as bar:
                out = self.predictor.predict_db(tx, rx, freqs, chunk_links, bar, axes)
        if self.residual_terms is None:
            return out, (out.copy() if physics_only else None)
        terms = self.residual_terms.apply_db(tx, rx)[:, None]
        return np.maximum(out + terms, FLOOR_DB), (out if physics_only else None)


class _Advance:
    """A progress task whose advance(n) calls a caller's function (RoomPredictor.path_gain_db reports to one)."""

    def __init__(self, advance):
        self.advance = advance
