"""Fixtures of the edit tests: a two-box scene (600 Gaussians labelled "crate" and "chair")."""
import numpy as np
import pytest

from rfir_cli.artifacts import write_artifact
from rfir_stages.geom import gaussians_from_mesh
from rfir_stages.simulate.scenes import box


def two_boxes() -> tuple[dict, dict]:
    """Two 10 cm surfel boxes (label 0 "crate" at x = -0.2 m, label 1 "chair" at x = +0.2 m) with random
    rf materials and per-Gaussian model/diffuse_* arrays. Returns (data, free) for write_artifact."""
    parts = []
    for label, x in ((0, -0.2), (1, 0.2)):
        v, f = box((x - 0.05, -0.05, -0.05), (x + 0.05, 0.05, 0.05))
        fields = gaussians_from_mesh(v, f, 0.03)
        fields["gaussians/labels"] = np.full(len(fields["gaussians/means"]), label, np.int64)
        parts.append(fields)
    data = {k: np.concatenate([p[k] for p in parts]) for k in parts[0] if k.startswith("gaussians/")}
    g = len(data["gaussians/means"])
    rng = np.random.default_rng(7)
    data.update({"rf/opacity": rng.uniform(0.5, 1, g), "rf/roughness": rng.uniform(2, 20, g),
                 "rf/gamma_abs": rng.uniform(0.3, 1, g), "rf/gamma_phase_rad": rng.uniform(-3, 3, g),
                 "rf/freq_hz": np.array([10e9])})
    free = {"model": {"s_tx_db": np.zeros(1), "diffuse_abs": rng.uniform(0, 0.1, g),
                      "diffuse_roughness": rng.uniform(1, 3, g), "@attrs": {"antenna_kind": "isotropic"}}}
    return data, free


def write_rf(path, keep: np.ndarray | None = None):
    """Write the two-box rf artifact to path; keep [G] bool: write only those Gaussians."""
    data, free = two_boxes()
    if keep is not None:
        g = len(keep)
        data = {k: (v[keep] if k != "rf/freq_hz" else v) for k, v in data.items()}
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
