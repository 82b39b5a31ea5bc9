"""scripts/baseline_raytrace.py on a survey with unknown transmit power: the system gain, the choice of a
material set on the training links, devices matched by ids of any form; and its steps in the measured target.
No Sionna: the scoring is checked on synthetic predictions."""
from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[2] / "scripts" / "baseline_raytrace.py"


@pytest.fixture(scope="module")
def rt():
    spec = importlib.util.spec_from_file_location("baseline_raytrace_cli", SCRIPT)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_the_system_gain_is_the_mean_training_residual_and_ignores_test_rows(rt):
    rng = np.random.default_rng(1)
    pred = rng.normal(-70, 8, 200)
    meas = pred + 23.5                              # the unknown transmit power and antenna gains
    train = np.arange(200) < 150
    meas[~train] += 40.0                            # test rows must not move the fitted gain
    assert rt.fit_system_gain(pred, meas, train) == pytest.approx(23.5, abs=1e-12)
    noise = rng.normal(0, 2, 200)
    got = rt.score(pred, pred + 23.5 + noise, train, ~train)
    assert got["system_gain_db"] == pytest.approx(23.5 + noise[train].mean(), abs=1e-12)
    assert got["mae_db"] == pytest.approx(np.mean(np.abs(noise[~train] - noise[train].mean())), abs=1e-12)
    pred_nopath = pred.copy()
    pred_nopath[:10] = -250.0                       # links without a path do not enter the fit
    assert rt.fit_system_gain(pred_nopath, meas, train) == pytest.approx(23.5, abs=1e-12)
    with pytest.raises(ValueError, match="no training link"):
        rt.fit_system_gain(np.full(5, -250.0), np.zeros(5), np.ones(5, bool))


def test_the_material_set_is_chosen_by_the_training_links_only(rt):
    rng = np.random.default_rng(2)
    truth = rng.normal(-70, 8, 300)
    train = np.arange(300) % 5 != 0
    shape = rng.normal(0, 4, 300)                   # a set that mispredicts the link-to-link shape
    good_on_test_only = np.where(train, truth + shape, truth - 17.0)
    cands = np.stack([truth + shape, truth - 11.0, good_on_test_only])
    best, maes = rt.choose_candidate(cands, truth, train)
    assert best == 1                                # a constant offset is absorbed by its own gain
    assert maes[1] == pytest.approx(0.0, abs=1e-9)
    assert maes[0] == pytest.approx(maes[2], abs=1e-12) and maes[0] > 1.0   # equal on the training rows
    # ties go to the earlier set
    best_tie, _ = rt.choose_candidate(np.stack([truth + 3.0, truth - 3.0]), truth, train)
    assert best_tie == 0


def test_devices_of_any_id_form_and_a_moved_device_is_an_error(rt):
    ids = np.array(["b7", "a", "b7", "z-3", "a"])
    pos = np.array([[1, 0, 0], [2, 0, 0], [1, 0, 0], [3, 0, 0], [2, 0, 0.0005]], float)
    names, table, index = rt.device_table(ids, pos, "receiver", "f.h5")
    assert names.tolist() == ["a", "b7", "z-3"] and index.tolist() == [1, 0, 1, 2, 0]
    np.testing.assert_allclose(table[index], pos, atol=1e-3)
    names, _, index = rt.device_table(np.array([42, 10, 42, 11]), np.zeros((4, 3)), "receiver", "f.h5")
    assert names.tolist() == ["10", "11", "42"] and index.tolist() == [2, 0, 2, 1]      # gaps are fine
    pos[2, 0] = 1.5
    with pytest.raises(ValueError, match=r"f\.h5: receiver 'b7' is at more than one position"):
        rt.device_table(ids, pos, "receiver", "f.h5")


def test_sweep_predictions_are_matched_to_rows_by_id(rt, tmp_path):
    tx_ids, rx_ids = np.array(["0", "5", "9"]), np.array(["10", "12", "x"])
    tx_pos = np.array([[0, 0, 1], [5, 0, 1], [9, 0, 1.0]])
    rx_pos = np.array([[0, 10, 2], [0, 12, 2], [0, 20, 2.0]])
    k, a, b = np.meshgrid(np.arange(2), np.arange(3), np.arange(3), indexing="ij")
    pred = -(100.0 * k + 10.0 * a + b)              # encodes (set, transmitter, receiver)
    npz = tmp_path / "sweep.npz"
    np.savez(npz, pred_db=pred, tx_ids=tx_ids, rx_ids=rx_ids, tx_pos=tx_pos, rx_pos=rx_pos, info=json.dumps({"a": 1}))
    rows_tx, rows_rx = np.array([9, 0, 5, 9]), np.array(["x", "12", "10", "10"])
    meas = {"tx_id": rows_tx, "rx_id": rows_rx, "tx_pos": tx_pos[[2, 0, 1, 2]], "rx_pos": rx_pos[[2, 1, 0, 0]]}
    got, info = rt.link_predictions(npz, meas, "m.h5")
    assert info == {"a": 1}
    np.testing.assert_array_equal(got, [[-22, -1, -10, -20], [-122, -101, -110, -120]])
    meas["rx_id"] = np.array(["x", "13", "10", "10"])
    with pytest.raises(ValueError, match=r"m\.h5: receivers \['13'\] are not in the sweep"):
        rt.link_predictions(npz, meas, "m.h5")


def test_candidates_vary_the_walls_only_and_drop_repeats(rt):
    labels = [{"label": 0, "name": "concrete_00", "radio_material": "concrete", "thickness_m": 0.25},
              {"label": 3, "name": "concrete_01", "radio_material": "concrete", "thickness_m": 0.12},
              {"label": 4, "name": "floor_concrete", "radio_material": "concrete", "thickness_m": 0.2},
              {"label": 5, "name": "ceiling", "radio_material": "wood", "thickness_m": 0.05}]
    cands = rt.candidates(labels, ["concrete", "brick", "metal"], ["plan", "0.1"])
    names = [c["name"] for c in cands]
    # labels first; "walls concrete plan" repeats it; metal once (an opaque slab)
    assert names == ["labels", "walls concrete 0.1 m", "walls brick plan", "walls brick 0.1 m", "walls metal plan"]
    brick = cands[2]["materials"]
    assert brick[0] == ("brick", 0.25) and brick[3] == ("brick", 0.12)
    assert brick[4] == ("concrete", 0.2) and brick[5] == ("wood", 0.05)
    assert cands[1]["materials"][3] == ("concrete", 0.1)


def test_the_measured_target_scores_one_sweep_on_each_protocol():
    from rfir_stages.reproduce.measured_target import MEASURED_PROTOCOLS
    from rfir_stages.reproduce.targets import declare

    plan, tables = declare(["measured"], False)
    sweep = plan.steps["measured__raytrace_sweep"]
    assert sweep.argv[2] == "sweep" and any(i.endswith("measured/room.ply") for i in sweep.inputs)
    for name, _, _ in MEASURED_PROTOCOLS:
        score = plan.steps[f"measured_{name}__raytrace_gain"]
        assert score.argv[2] == "score"
        assert sweep.outputs[0] in score.inputs
        assert any(i.endswith(f"measured/survey_{name}.h5") for i in score.inputs)
    quick, _ = declare(["measured"], True)
    assert "--wall-materials" not in sweep.argv
    assert quick.steps["measured__raytrace_sweep"].argv[-4:] == ["--wall-materials", "concrete,brick,metal",
                                                                 "--wall-thickness", "plan"]
