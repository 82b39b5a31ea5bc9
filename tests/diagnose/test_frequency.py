"""`rfir diagnose` with measurements at another frequency than the model was fitted at: the room model predicts
at the measured frequency and says so; one outside its material laws' range is refused in one line.

The model is a room whose every material is air (free space, tests/rssi/helpers.py `write_air_room`); the
measurements are free space (Friis, an independent closed form) at 5.8 GHz plus 0.3 dB of seeded noise. Predicted at
5.8 GHz the held-out MAE is the noise's (~0.24 dB); at the fitted 2.4 GHz it would be 20 log10(5.8 / 2.4) = 7.7 dB.
"""
import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from rfir_cli.main import app
from rfir_core.artifacts import write_artifact

# tests/diagnose is a package of its own, so the shared builder of tests/rssi/helpers.py is loaded by its path
_spec = importlib.util.spec_from_file_location("rssi_helpers", Path(__file__).resolve().parents[1] / "rssi" / "helpers.py")
_helpers = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(_helpers)
write_air_room = _helpers.write_air_room

C0 = 299_792_458.0


def write_free_space_measurements(path, freq_hz: float, noise_db: float = 0.3):
    """RSSI measurements of 120 links inside the room: Friis at freq_hz plus seeded Gaussian noise (dB)."""
    rng = np.random.default_rng(5)
    tx = rng.uniform([0.3, 0.3, 1.5], [3.7, 2.7, 2.2], (120, 3))
    rx = rng.uniform([0.3, 0.3, 0.8], [3.7, 2.7, 1.4], (120, 3))
    friis = 20 * np.log10(C0 / freq_hz / (4 * math.pi * np.linalg.norm(rx - tx, axis=1)))
    data = {"tx_pos": tx, "rx_pos": rx, "freq_hz": np.array([freq_hz]),
            "path_gain_db": (friis + rng.normal(0, noise_db, len(tx)))[:, None],
            "split": (np.arange(len(tx)) % 3 == 0).astype(np.int64), "scene_bounds": np.array([[0, 0, 0], [4, 3, 2.5]])}
    return write_artifact(path, "measurements", data, attrs={"task": "rssi", "scene": "air room"})


@pytest.fixture(scope="module")
def air_room(tmp_path_factory):
    return write_air_room(tmp_path_factory.mktemp("air") / "rf.h5")


def _invoke(*args):
    return CliRunner().invoke(app, [str(a) for a in args])


def test_diagnose_predicts_at_the_measured_frequency(air_room, tmp_path):
    meas = write_free_space_measurements(tmp_path / "meas.h5", 5.8e9)
    r = _invoke("diagnose", air_room, meas, "-o", tmp_path / "report", "--max-effects", "1")
    assert r.exit_code == 0, r.output
    said = " ".join(r.output.split())
    assert "predicted at 5.8 GHz (the measurements' frequencies; the model was fitted at 2.4 GHz)" in said, said
    results = json.loads((tmp_path / "report" / "results.json").read_text())
    # the noise's MAE, 0.3 * sqrt(2 / pi) = 0.24 dB; at the fitted 2.4 GHz every row would be 7.7 dB off
    assert results["mae_before_db"] < 0.5, results["mae_before_db"]
    assert "5.8 GHz" in results["info"]["frequencies"]
    assert "Predicted at 5.8 GHz" in (tmp_path / "report" / "report.md").read_text()


def test_diagnose_at_the_fitted_frequency_says_so(air_room, tmp_path):
    meas = write_free_space_measurements(tmp_path / "meas.h5", 2.4e9)
    r = _invoke("diagnose", air_room, meas, "-o", tmp_path / "report", "--max-effects", "1")
    assert r.exit_code == 0, r.output
    assert "predicted at 2.4 GHz (measured, and what the model was fitted at)" in " ".join(r.output.split())
    assert json.loads((tmp_path / "report" / "results.json").read_text())["mae_before_db"] < 0.5


def test_diagnose_refuses_measurements_outside_the_material_laws_range(air_room, tmp_path):
    meas = write_free_space_measurements(tmp_path / "meas.h5", 150e9)
    r = _invoke("diagnose", air_room, meas, "-o", tmp_path / "report")
    lines = [x for x in r.output.splitlines() if x.strip()]
    assert r.exit_code != 0 and "Traceback" not in r.output, r.output
    assert len(lines) == 1 and "meas.h5: the measured frequency 150 GHz is outside 1-100 GHz" in lines[0], r.output


class _Model:
    """What prediction_frequencies reads of a RadioModel: task, fitted_freqs_hz, default_freqs (the fitted
    frequencies among the measured ones, as RadioModel.default_freqs)."""

    def __init__(self, task, fitted_hz):
        self.task, self.fitted_freqs_hz = task, np.asarray(fitted_hz, np.float64)

    def default_freqs(self, measured_hz):
        f = np.asarray(measured_hz, np.float64)
        return f[[bool(np.any(np.abs(self.fitted_freqs_hz - x) <= 1e-6 * x)) for x in f]]


def test_which_frequencies_each_model_kind_predicts():
    from rfir_stages.diagnose.data import prediction_frequencies

    room, obj = _Model("rssi", [2.4e9]), _Model("rcs", [10e9])
    np.testing.assert_array_equal(prediction_frequencies(room, [2.4e9, 5.8e9])[0], [2.4e9, 5.8e9])
    # the object model: the fitted one where measured, else the measured ones (it predicts at any frequency)
    np.testing.assert_array_equal(prediction_frequencies(obj, [10e9, 12e9])[0], [10e9])
    freqs, why = prediction_frequencies(obj, [12e9])
    np.testing.assert_array_equal(freqs, [12e9])
    assert why == "12 GHz (the measurements' frequencies; the model was fitted at 10 GHz)"
