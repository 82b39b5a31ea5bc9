"""The figures of the edit validation against the simulator (stages/edit/validate.py)."""
import numpy as np

from rfir_stages.edit.validate import change_metrics


def test_a_model_that_predicts_the_change_exactly():
    rng = np.random.default_rng(0)
    meas_before = rng.normal(-70, 8, 400)
    change = np.where(np.arange(400) < 100, rng.normal(-6, 2, 400), 0.0)
    bias = rng.normal(0, 2, 400)                    # the model's own error, the same before and after
    test = np.arange(400) % 5 == 0
    m = change_metrics(meas_before + bias, meas_before + bias + change, meas_before, meas_before + change, test)
    assert np.isclose(m["change_correlation"], 1.0) and np.isclose(m["mae_ratio"], 1.0)
    assert m["not_edited_mae_db"] > m["edited_mae_db"] and m["num_test"] == 80
    assert m["links_changed_over_1db"] >= 90


def test_a_model_that_ignores_the_edit():
    rng = np.random.default_rng(1)
    meas_before = rng.normal(-70, 8, 400)
    change = rng.normal(0, 4, 400)
    pred = meas_before + 1.0
    m = change_metrics(pred, pred, meas_before, meas_before + change, np.ones(400, bool))
    assert np.isnan(m["change_correlation"]) and m["predicted_change_mean_abs_db"] == 0
    assert np.isclose(m["edited_mae_db"], m["not_edited_mae_db"]) and m["mae_ratio"] > 2


def test_rank_correlation_is_not_dominated_by_a_few_glints():
    """Two links whose simulated change is a 35 dB glint the model misses: Pearson falls, Spearman holds."""
    rng = np.random.default_rng(2)
    meas_before = rng.normal(-70, 8, 400)
    change = rng.normal(0, 2, 400)
    pred_change = change + rng.normal(0, 0.3, 400)
    change[:2] = [35.0, -35.0]
    pred_change[:2] = 0.0
    m = change_metrics(meas_before + 1, meas_before + 1 + pred_change, meas_before, meas_before + change, np.ones(400, bool))
    assert m["change_correlation"] < 0.7
    assert m["change_rank_correlation"] > 0.9
