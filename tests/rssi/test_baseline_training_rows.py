"""`predict rssi` scores the fitted baselines on the training rows too, and says when one fits them better
than the model (the issue's "rfir printed the baselines and said nothing")."""
import json

import numpy as np
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact
from rfir_cli.main import app

from .helpers import write_measurements, write_scene

# a short fit of the room model
FAST = ["--set", "rf_fit.physical.iterations=20", "--set", "rf_fit.physical.start_iterations=5"]


def test_baselines_training_error_is_reported_and_compared(tmp_path):
    write_scene(tmp_path / "scene.h5")
    write_measurements(tmp_path / "meas.h5")
    run = CliRunner()
    r = run.invoke(app, [*FAST, "rf-fit", str(tmp_path / "scene.h5"), str(tmp_path / "meas.h5"), "-o",
                         str(tmp_path / "rf.h5")])
    assert r.exit_code == 0, r.output
    res = tmp_path / "res.json"
    r = run.invoke(app, [*FAST, "predict", "rssi", str(tmp_path / "rf.h5"), "--measurements", str(tmp_path / "meas.h5"),
                         "-o", str(tmp_path / "p.h5"), "--results", str(res)])
    assert r.exit_code == 0, r.output
    doc = json.loads(res.read_text())
    m = doc["metrics"]
    # the log-distance fit on the training rows, by an independent least squares (numpy polyfit)
    meas = read_artifact(tmp_path / "meas.h5", "measurements")
    train = np.asarray(meas["split"]) == 0
    d = np.linalg.norm(meas["rx_pos"] - meas["tx_pos"], axis=1)[train]
    y = np.asarray(meas["path_gain_db"])[train, 0]
    slope, icpt = np.polyfit(-10 * np.log10(d), y, 1)
    assert abs(m["baseline_log_distance_mae_train_db"] - np.mean(np.abs(icpt - 10 * slope * np.log10(d) - y))) < 1e-9
    # multi-wall has every log-distance regressor and more: never worse on the rows it was fitted on (in RMS;
    # in MAE up to a little)
    assert m["baseline_multiwall_mae_train_db"] <= m["baseline_log_distance_mae_train_db"] + 0.05
    said = "; ".join(doc["warnings"]) + r.output     # in the results JSON and printed
    for name in ("log_distance", "multiwall"):
        beats = m[f"baseline_{name}_mae_train_db"] < m["mae_train_db"]
        line = f"the {name.replace('_', ' ')} baseline beats rfir on the training rows"
        assert (line in said) == beats, (name, m)
