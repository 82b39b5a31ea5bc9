import numpy as np
import pytest

from rfir_core.artifacts import write_artifact
from rfir_core.provenance import Provenance


def measurement_data(links: int = 5, freqs: int = 2) -> dict:
    rng = np.random.default_rng(0)
    return {
        "tx_pos": rng.normal(size=(links, 3)),
        "rx_pos": rng.normal(size=(links, 3)),
        "freq_hz": np.linspace(2.4e9, 2.5e9, freqs),
        "path_gain_db": rng.uniform(-90, -40, size=(links, freqs)),
        "split": (np.arange(links) % 2).astype(np.int64),
    }


@pytest.fixture(name="measurement_data")
def measurement_data_factory():
    return measurement_data


@pytest.fixture
def measurements_file(tmp_path):
    return write_artifact(tmp_path / "m.h5", "measurements", measurement_data(),
                          attrs={"task": "rssi", "scene": "unit"}, provenance=Provenance(stage="test"))
