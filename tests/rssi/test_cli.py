"""`rfir rf-fit` on RSSI data (the room model) and `rfir predict rssi` / `rfir edit` end to end on the
reduced room (seconds), and the bad input around them."""
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact, write_artifact
from rfir_cli.main import app

from .helpers import write_measurements, write_scene

# a short fit of the room model: the assertions below are about the plumbing, not the accuracy
FAST = ["--set", "rf_fit.physical.iterations=20", "--set", "rf_fit.physical.start_iterations=5"]


def _invoke(args, sets=()):
    return CliRunner().invoke(app, [*FAST, *sets, *map(str, args)])


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    d = tmp_path_factory.mktemp("rssi")
    write_scene(d / "scene.h5")
    write_measurements(d / "meas.h5")
    r = _invoke(["rf-fit", d / "scene.h5", d / "meas.h5", "-o", d / "rf.h5"])
    assert r.exit_code == 0, r.output
    return d


def test_fit_writes_a_room_model_that_learned(fitted):
    rf = read_artifact(fitted / "rf.h5", "rf")
    assert rf.free["model@attrs"]["model_kind"] == "rssi_physical"
    t = rf.free["training@attrs"]
    assert t["train_mae_db"] < t["initial_mae_db"]
    assert len(rf["material/index"]) == len(rf["gaussians/means"])


def test_scoring_writes_results_beside_baselines(fitted, tmp_path):
    res = tmp_path / "res.json"
    r = _invoke(["predict", "rssi", fitted / "rf.h5", "--measurements", fitted / "meas.h5", "-o", tmp_path / "p.h5",
                 "--results", res, "--plots", tmp_path / "plots"])
    assert r.exit_code == 0, r.output
    m = json.loads(res.read_text())["metrics"]
    meas = read_artifact(fitted / "meas.h5")
    assert m["num_test"] == int((meas["split"] == 1).sum())
    for k in ("mae_db", "baseline_log_distance_mae_db", "baseline_multiwall_mae_db"):
        assert np.isfinite(m[k])
    # the data has a wall loss the log-distance model cannot see: the multi-wall fit must do better
    assert m["baseline_multiwall_mae_db"] < m["baseline_log_distance_mae_db"]
    names = {p.name for p in (tmp_path / "plots").iterdir()}
    assert {"rssi_predicted.png", "rssi_measured.png", "rssi_error.png", "fov_attributes.png"} <= names
    pred = read_artifact(tmp_path / "p.h5", "predictions")
    assert pred["path_gain_db"].shape == (len(meas["tx_pos"]), 1)


def test_map_for_a_new_transmitter_and_outside_warning(fitted, tmp_path):
    out = tmp_path / "map.h5"
    r = _invoke(["predict", "rssi", fitted / "rf.h5", "--tx", "1.2,2.0,1.8", "--grid", "1.0,0.5", "-o", out])
    assert r.exit_code == 0, r.output
    pred = read_artifact(out, "predictions")
    assert len(pred["rx_pos"]) == 8 * 6 and np.isfinite(pred["path_gain_db"]).all()
    r = _invoke(["predict", "rssi", fitted / "rf.h5", "--tx", "9,1,1", "--grid", "1.0,0.5", "-o", tmp_path / "o.h5"])
    assert r.exit_code == 0 and "outside the scene's bounds" in r.output and "(9.00, 1.00, 1.00)" in r.output


def test_holdout_transmitters_are_scored(fitted, tmp_path):
    sets = ["--set", "rf_fit.rssi.split=holdout_tx", "--set", "rf_fit.rssi.holdout_tx=1",
            "--set", "rf_fit.physical.iterations=5", "--set", "rf_fit.physical.start_iterations=2"]
    r = _invoke(["rf-fit", fitted / "scene.h5", fitted / "meas.h5", "-o", tmp_path / "rf.h5"], sets)
    assert r.exit_code == 0, r.output
    res = tmp_path / "r.json"
    r = _invoke(["predict", "rssi", tmp_path / "rf.h5", "--measurements", fitted / "meas.h5", "-o", tmp_path / "p.h5",
                 "--results", res])
    assert r.exit_code == 0, r.output
    m = json.loads(res.read_text())["metrics"]
    assert m["num_test"] == 30 and m["num_train"] == 90 and "held out" in m["split"]


def test_bad_input_is_one_line_and_writes_nothing(fitted, tmp_path):
    out = tmp_path / "x.h5"
    r = _invoke(["predict", "rssi", fitted / "rf.h5", "--tx", "1,1,1", "--grid", "1.0,0.0005", "-o", out])
    assert r.exit_code == 5 and "GiB" in r.output and not out.exists()
    bad = tmp_path / "rx.csv"
    bad.write_text("x,y,z\n1,2\n")
    r = _invoke(["predict", "rssi", fitted / "rf.h5", "--tx", "1,1,1", "--rx", bad, "-o", out])
    assert r.exit_code == 2 and "rx.csv" in r.output and not out.exists()
    r = _invoke(["predict", "rssi", fitted / "rf.h5", "--tx", "1,1", "-o", out])
    assert r.exit_code == 4 and "--tx" in r.output
    r = _invoke(["predict", "rssi", fitted / "rf.h5", "-o", out])
    assert r.exit_code == 4 and not out.exists()
    r = _invoke(["predict", "rssi", fitted / "meas.h5", "--tx", "1,1,1", "-o", out])
    assert r.exit_code == 3 and not out.exists()
    assert "Traceback" not in r.output


def test_settings_of_other_rssi_models_are_refused(fitted, tmp_path):
    for key in ("model=free", "weighting=false", "probe_step_m=0.5"):
        r = _invoke(["rf-fit", fitted / "scene.h5", fitted / "meas.h5", "-o", tmp_path / "rf.h5"],
                    ["--set", f"rf_fit.rssi.{key}"])
        assert r.exit_code == 4 and f"unknown config key 'rf_fit.rssi.{key.split('=')[0]}'" in r.output, r.output
        assert not (tmp_path / "rf.h5").exists() and "Traceback" not in r.output


def test_an_artifact_of_the_los_nlos_model_is_refused_in_one_line(fitted, tmp_path):
    art = read_artifact(fitted / "rf.h5", "rf")
    free = art.free_for_write()
    free["model"]["@attrs"]["model_kind"] = "rssi_los_nlos"
    old = write_artifact(tmp_path / "old.h5", "rf", dict(art.data), attrs=dict(art.attrs), free=free)
    out = tmp_path / "o.h5"
    for args in (["predict", "rssi", old, "--tx", "1,1,1", "--grid", "1.0,0.5", "-o", out],
                 ["edit", old, "-o", out, "--select", "label:partition", "--op", "delete"]):
        r = _invoke(args)
        assert r.exit_code == 3, r.output
        lines = [ln for ln in r.output.splitlines() if ln.strip()]
        assert len(lines) == 1 and "old.h5" in lines[0] and "rssi_los_nlos" in lines[0] and "rf-fit" in lines[0], lines
        assert not out.exists()


def test_setting_free_attributes_of_a_room_model_is_refused(fitted, tmp_path):
    out = tmp_path / "e.h5"
    r = _invoke(["edit", fitted / "rf.h5", "-o", out, "--select", "label:partition", "--op", "set:gamma_abs=1"])
    assert r.exit_code == 4 and "material:NAME" in r.output and "Traceback" not in r.output, r.output
    assert not out.exists()


def test_edit_of_a_room_model_maps_the_change(fitted, tmp_path):
    rf = read_artifact(fitted / "rf.h5", "rf")
    names = [str(n) for n in rf.attrs["label_names"]]
    part = int(np.sum(np.asarray(rf["gaussians/labels"]) == names.index("partition")))
    out, plot = tmp_path / "no_partition.h5", tmp_path / "edit.png"
    r = _invoke(["edit", fitted / "rf.h5", "-o", out, "--select", "label:partition", "--op", "delete",
                 "--plot", plot, "--map-tx", "1.0,2.0,2.0"])
    assert r.exit_code == 0, r.output
    edited = read_artifact(out, "rf")
    g = len(edited["gaussians/means"])
    assert g == len(rf["gaussians/means"]) - part and len(edited["material/index"]) == g
    assert (tmp_path / "edit_radio.png").stat().st_size > 1000 and "mean |change|" in r.output
    # the map now differs behind the removed partition (Tx at x = 1 m, receivers on both sides)
    before = _invoke(["predict", "rssi", fitted / "rf.h5", "--tx", "1.0,2.0,2.0", "--grid", "1.0,0.5", "-o", tmp_path / "a.h5"])
    after = _invoke(["predict", "rssi", out, "--tx", "1.0,2.0,2.0", "--grid", "1.0,0.5", "-o", tmp_path / "b.h5"])
    assert before.exit_code == 0 and after.exit_code == 0, before.output + after.output
    a, b = (np.asarray(read_artifact(tmp_path / n, "predictions")["path_gain_db"]) for n in ("a.h5", "b.h5"))
    behind = np.asarray(read_artifact(tmp_path / "a.h5", "predictions")["rx_pos"])[:, 0] > 2.0
    assert np.max(np.abs(a - b)[behind]) > 0.5
