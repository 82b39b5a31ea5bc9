"""Fixtures of the edit tests: a two-box scene (600 Gaussians labelled "crate" and "chair") with a
physical model (one material per box, rfir_stages.model.artifact.physical_fields)."""
import numpy as np
import pytest
import torch

from rfir_core.artifacts import write_artifact
from rfir_stages.geom import gaussians_from_mesh
from rfir_stages.model.artifact import physical_fields
from rfir_stages.model.physical import MaterialValues, PairSettings
from rfir_stages.model.surfels import surfel_areas
from rfir_stages.simulate.scenes import box


def two_boxes() -> tuple[dict, dict]:
    """Two 10 cm surfel boxes (label 0 "crate" at x = -0.2 m, label 1 "chair" at x = +0.2 m), a material
    each (wood-like and concrete-like slabs) and a per-Gaussian model/tag array (a free-group dataset
    of length G). Returns (data, free) for write_artifact."""
    parts = []
    for label, x in ((0, -0.2), (1, 0.2)):
        v, f = box((x - 0.05, -0.05, -0.05), (x + 0.05, 0.05, 0.05))
        fields = gaussians_from_mesh(v, f, 0.03)
        fields["gaussians/labels"] = np.full(len(fields["gaussians/means"]), label, np.int64)
        parts.append(fields)
    data = {k: np.concatenate([p[k] for p in parts]) for k in parts[0] if k.startswith("gaussians/")}
    g = len(data["gaussians/means"])
    t = lambda k: torch.as_tensor(data[f"gaussians/{k}"], dtype=torch.float64)  # noqa: E731
    mats = MaterialValues(torch.tensor([2.0, 5.3]), torch.tensor([0.01, 0.05]), 1.0, torch.tensor([0.1, 0.3]),
                          torch.tensor([0.02, 0.05]))
    model, attrs = physical_fields(mats, torch.as_tensor(data["gaussians/labels"]),
                                   surfel_areas(t("means"), t("log_scales"), t("rotations"), t("normals")),
                                   np.array([10e9]), PairSettings(), ["crate", "chair"], 0.0)
    data.update(model)
    data["rf/freq_hz"] = np.array([10e9])
    tag = np.random.default_rng(7).uniform(0, 1, g)
    free = {"model": {"tag": tag, "@attrs": {**attrs, "antenna_kind": "isotropic"}}}
    return data, free


def write_rf(path, keep: np.ndarray | None = None):
    """Write the two-box rf artifact to path; keep [G] bool: write only those Gaussians."""
    data, free = two_boxes()
    if keep is not None:
        g = len(keep)
        data = {k: (v[keep] if k.startswith(("gaussians/", "rf/", "material/index", "material/area_m2"))
                    and k != "rf/freq_hz" else v) for k, v in data.items()}
        free["model"] = {k: (v[keep] if hasattr(v, "__len__") and len(v) == g else v) for k, v in free["model"].items()}
    attrs = {"task": "rcs", "label_names": np.asarray(["crate", "chair"], dtype=object)}
    return write_artifact(path, "rf", data, attrs=attrs, free=free)


@pytest.fixture
def rf_path(tmp_path):
    return write_rf(tmp_path / "rf.h5")


@pytest.fixture(name="write_rf")
def _write_rf_fixture():
    """The write_rf function, for tests that write a second scene."""
    return write_rf
