"""Objects a Tx-Rx segment crosses, counted on the Gaussians of a scene or rf artifact: what the crossing effects
of `rfir diagnose` read, both when it loads its rows (data.py) and when `rfir predict` applies recorded effects
(apply.py), which import it from here."""
from __future__ import annotations

import numpy as np

from rfir_stages.model.crossings import crossing_counts
from rfir_stages.model.links import geometry_from_artifact
from rfir_stages.model.occlusion import make_provider


def crossings_from_artifact(art, tx: np.ndarray, rx: np.ndarray) -> np.ndarray:
    """Objects crossed by each Tx-Rx segment [L] (Gaussians of a scene or rf artifact, labels if any)."""
    geom = geometry_from_artifact(art)
    provider = make_provider("auto", geom)
    names = art.attrs.get("label_names")
    counts, _ = crossing_counts(provider, art.get("gaussians/labels"), None if names is None else list(names), tx, rx)
    return counts.sum(1)
