"""A fitted baseline that beats rfir on the test rows is said: in predict's closing lines and the results JSON."""
import json

import numpy as np
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact, write_artifact
from rfir_stages.geom import gaussians_from_mesh, write_scene_artifact
from rfir_stages.predict.baselines import baselines_beating_model

from .test_stage import BOX, FAST, _app, _measurements


def test_each_baseline_below_the_model_is_named():
    metrics = {"mae_db": 3.0, "baseline_nearest_mae_db": 2.5, "baseline_linear_mae_db": 3.5,
               "baseline_multiwall_mae_db": 1.0, "baseline_log_distance_params": {"n": 2.0}, "mae_train_db": 0.1}
    got = baselines_beating_model(metrics)
    assert len(got) == 2
    assert "nearest baseline beats rfir on the test rows: 2.50 dB against 3.00 dB" in got[0]
    assert "multiwall" in got[1]
    assert baselines_beating_model({"mae_db": 1.0, "baseline_nearest_mae_db": 2.0}) == []
    assert baselines_beating_model({"baseline_nearest_mae_db": 2.0}) == []          # nothing scored


def test_predict_rcs_warns_when_a_baseline_beats_the_model(tmp_path, monkeypatch):
    """Measurements flat over aspect (a sphere would do that): copying the nearest training aspect is
    exact, a metal box's physical model is not."""
    v, f = BOX
    write_scene_artifact(tmp_path / "scene.h5", gaussians_from_mesh(v, f, 0.03))
    meas = read_artifact(_measurements(tmp_path / "box.h5"), "measurements")
    data = dict(meas.data)
    for k in ("path_gain_db", "rcs_dbsm"):
        data[k] = np.full_like(data[k], float(np.mean(data[k])))
    write_artifact(tmp_path / "meas.h5", "measurements", data, attrs=dict(meas.attrs))
    app = _app(FAST)
    r = CliRunner().invoke(app, ["rf-fit", str(tmp_path / "scene.h5"), str(tmp_path / "meas.h5"),
                                 "-o", str(tmp_path / "rf.h5")])
    assert r.exit_code == 0, r.output
    monkeypatch.chdir(tmp_path)
    r = CliRunner().invoke(app, ["predict", "rcs", str(tmp_path / "rf.h5"), "--measurements",
                                 str(tmp_path / "meas.h5"), "-o", str(tmp_path / "pred.h5")])
    assert r.exit_code == 0, r.output
    m = json.loads((tmp_path / "pred.json").read_text())["metrics"]
    better = [k for k in m if k.startswith("baseline_") and k.endswith("_mae_db") and m[k] < m["mae_db"]]
    assert better, m                                   # the setup: at least one baseline beats the model
    said = m["warning_baselines"]
    out = " ".join(r.output.split())
    for k in better:
        name = k[len("baseline_"):-len("_mae_db")].replace("_", " ")
        assert f"the {name} baseline beats rfir" in said and f"the {name} baseline beats rfir" in out
    assert np.isfinite(m["mae_db"])
