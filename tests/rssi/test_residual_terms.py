"""Residual terms of the room model (stages/model/residual_terms.py, stages/rf_fit/residual_choice.py,
docs/physics.md 8.15): synthetic residuals made by a known pattern, a known block of excess loss along the
links, a smooth field over the positions, or noise alone; and a stored model predicting with its terms."""
import numpy as np
import pytest

from rfir_core.artifacts import read_artifact, write_artifact
from rfir_stages.model.radio_model import load_model
from rfir_stages.model.residual_terms import (FloorGrid, ResidualTerms, fit_linear, pattern_design,
                                              pattern_features)
from rfir_stages.rf_fit.residual_choice import choose_residual_terms, parse_request

from .helpers import write_air_room

ANCHORS = np.array([[0.5, 0.5, 2.2], [9.5, 0.5, 1.2], [9.5, 7.5, 2.2], [0.5, 7.5, 1.5], [5.0, 4.0, 2.6]])
FLOOR = (np.zeros(2), np.array([10.0, 8.0]))


def survey(num_positions: int = 160, seed: int = 1, anchors: np.ndarray = ANCHORS):
    """Links from a roaming tag at num_positions random positions (z 1.0-1.6 m) to every anchor of `anchors`:
    (tx [M, 3], rx [M, 3], ids), anchors on the rx side with their ids."""
    rng = np.random.default_rng(seed)
    tags = np.column_stack([rng.uniform(0.2, 9.8, num_positions), rng.uniform(0.2, 7.8, num_positions),
                            rng.uniform(1.0, 1.6, num_positions)])
    tx = np.repeat(tags, len(anchors), axis=0)
    rx = np.tile(anchors, (num_positions, 1))
    ids = {"tx": np.zeros(len(tx), np.int64), "rx": np.tile(np.arange(len(anchors)), num_positions)}
    return tx, rx, ids


def block_length_m(tx: np.ndarray, rx: np.ndarray, lo=(6.0, 2.0), hi=(7.5, 5.0), steps: int = 4000) -> np.ndarray:
    """Independent reference: the 3D length [M] m of each segment whose floor projection lies inside the
    rectangle lo..hi, by fine uniform sampling (not the model's grid)."""
    t = (np.arange(steps) + 0.5) / steps
    xy = tx[:, None, :2] + t[None, :, None] * (rx - tx)[:, None, :2]
    inside = ((xy >= lo) & (xy <= hi)).all(-1)
    return inside.mean(1) * np.linalg.norm(rx - tx, axis=1)


def test_pattern_coefficients_are_recovered():
    """Residuals made by a known per-anchor pattern a_d . f(u) plus 0.3 dB noise, anchors the tag surrounds (a
    corner anchor sees one quadrant, where the harmonics are nearly collinear): the ridge fit returns a_d to
    within 0.3 dB (the prior's shrinkage is s^2 / p^2 against 300 links)."""
    inner = np.array([[3.0, 3.0, 2.2], [7.0, 5.0, 2.5], [5.0, 4.0, 2.8]])
    tx, rx, ids = survey(300, anchors=inner)
    rng = np.random.default_rng(2)
    truth = rng.normal(0, 2.0, (len(inner), 5))
    device = ids["rx"]
    feats = pattern_features(rx, tx)
    r = (feats * truth[device]).sum(1) + rng.normal(0, 0.3, len(tx))
    a, x = fit_linear(r, pattern_design(device, feats, len(inner)), pattern_prior_db=3.0)
    assert x is None
    np.testing.assert_allclose(a.reshape(len(inner), 5), truth, atol=0.3)


def test_segment_lengths_match_a_fine_sampling():
    """W of the grid: each link's lengths over the cells sum to its 3D length inside the grid, and the length in a
    block of cells matches an independent fine sampling to within its two edges' sampling error (half a sample
    step, cell / 20, each, times the 3D / floor length ratio, at most 1.5 here)."""
    tx, rx, _ = survey(40)
    grid = FloorGrid.covering(*FLOOR, 0.5)
    w = grid.lengths(tx, rx)
    np.testing.assert_allclose(np.asarray(w.sum(1)).ravel(), np.linalg.norm(rx - tx, axis=1), rtol=1e-9)
    c = grid.centres()
    in_block = (c[:, 0] > 6.0) & (c[:, 0] < 7.5) & (c[:, 1] > 2.0) & (c[:, 1] < 5.0)
    np.testing.assert_allclose(w[:, in_block].sum(1).A.ravel(), block_length_m(tx, rx), atol=2 * 0.5 / 20 * 1.5)


def test_a_block_of_excess_loss_is_found_where_it_is():
    """Residuals made by 4 dB/m of excess loss inside a 1.5 x 3 m block (plus 0.5 dB noise): the choice takes the
    field, and the map's largest cell lies inside the block."""
    tx, rx, ids = survey()
    r = -4.0 * block_length_m(tx, rx) + np.random.default_rng(3).normal(0, 0.5, len(tx))
    choice = choose_residual_terms(tx, rx, ids, r, *FLOOR, seed=0)
    assert choice.terms is not None and "field" in choice.terms.which, choice.reason
    terms = choice.terms
    best = terms.grid.centres()[np.argmax(terms.field_db_per_m)]
    assert 6.0 <= best[0] <= 7.5 and 2.0 <= best[1] <= 5.0, best
    assert choice.scores["field"] < choice.scores["off"] - 0.3


def test_the_choice_takes_patterns_for_a_pattern():
    """Residuals made by per-anchor patterns alone: patterns are chosen, not the field."""
    tx, rx, ids = survey()
    rng = np.random.default_rng(4)
    truth = rng.normal(0, 3.0, (len(ANCHORS), 5))
    r = (pattern_features(rx, tx) * truth[ids["rx"]]).sum(1) + rng.normal(0, 0.5, len(tx))
    choice = choose_residual_terms(tx, rx, ids, r, *FLOOR, seed=0)
    assert choice.terms is not None and choice.terms.which[0] == "patterns", choice.reason
    assert "field" not in choice.terms.which, choice.reason


def test_a_smooth_field_over_positions_is_kriged_and_reverts_to_zero_far_away():
    """Residuals smooth over the tag's position, different per anchor (no pattern, no segment loss): kriging is
    chosen; 40 m from every surveyed position it adds nothing (physics alone)."""
    tx, rx, ids = survey(250)
    phase = np.arange(len(ANCHORS))[ids["rx"]]
    r = 3.0 * np.sin(tx[:, 0] * 1.3 + phase) * np.cos(tx[:, 1] * 0.9 - phase) \
        + np.random.default_rng(5).normal(0, 0.3, len(tx))
    choice = choose_residual_terms(tx, rx, ids, r, *FLOOR, seed=0)
    assert choice.terms is not None and "kriging" in choice.terms.which, choice.reason
    far = np.array([[50.0, 40.0, 1.3]] * len(ANCHORS))
    terms = ResidualTerms(choice.terms.side, choice.terms.device_pos_m, kriging_device=choice.terms.kriging_device,
                          kriging_pos_m=choice.terms.kriging_pos_m, kriging_weight_db=choice.terms.kriging_weight_db,
                          kriging_length_m=choice.terms.kriging_length_m)
    assert np.abs(terms.apply_db(far, ANCHORS)).max() < 1e-3
    near = terms.apply_db(tx[:50], rx[:50])
    assert np.abs(r[:50] - near).mean() < 0.6 * np.abs(r[:50]).mean()


def test_noise_alone_chooses_off():
    tx, rx, ids = survey()
    r = np.random.default_rng(6).normal(0, 3.0, len(tx))
    choice = choose_residual_terms(tx, rx, ids, r, *FLOOR, seed=0)
    assert choice.which == "off", choice.reason


def test_the_request_is_parsed_and_bad_names_refused():
    assert parse_request("auto") is None and parse_request("off") == ()
    assert parse_request("kriging+field") == ("field", "kriging")
    with pytest.raises(ValueError, match="furniture"):
        parse_request("field+furniture")


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    """(model without terms, the same with terms stored, a copy saved from it) of the free-space room."""
    d = tmp_path_factory.mktemp("terms")
    plain = write_air_room(d / "plain.h5")
    rf = read_artifact(plain, "rf")
    rng = np.random.default_rng(7)
    grid = FloorGrid.covering((0, 0), (4, 3), 0.5)
    terms = ResidualTerms("rx", np.array([[3.5, 2.5, 1.0], [0.5, 2.5, 1.0]]), rng.normal(0, 2, (2, 5)), grid,
                          np.where(rng.random(grid.num) < 0.5, rng.uniform(0, 2, grid.num), 0.0),
                          np.array([0, 0, 1]), np.array([[1.0, 1.0, 1.2], [2.0, 1.0, 1.2], [1.0, 2.0, 1.2]]),
                          np.array([1.5, -2.0, 0.7]), 1.0)
    free = rf.free_for_write()
    free["model"]["@attrs"].update(terms.attrs())
    free["model"].update(terms.table())
    with_terms = write_artifact(d / "terms.h5", "rf", dict(rf.data), attrs=dict(rf.attrs), free=free)
    saved = load_model(read_artifact(with_terms, "rf")).save(d / "saved.h5")
    return plain, with_terms, saved, terms


def test_predict_applies_the_stored_terms_and_a_saved_model_predicts_the_same(models):
    plain, with_terms, saved, terms = models
    tx = np.array([[1.2, 1.1, 1.3], [2.7, 0.8, 1.0], [0.7, 2.2, 1.4], [3.0, 1.5, 2.0]])
    rx = np.array([[3.5, 2.5, 1.0], [0.5, 2.5, 1.0], [3.5, 2.5, 1.0], [2.0, 2.0, 1.0]])   # the last: no device
    base = load_model(read_artifact(plain, "rf"))
    model = load_model(read_artifact(with_terms, "rf"))
    assert base.residual_terms is None
    want = base.predict(tx, rx)[:, 0] + terms.apply_db(tx, rx)
    np.testing.assert_allclose(model.predict(tx, rx)[:, 0], want, atol=1e-9)
    full, physics = model.predict_with_physics_only(tx, rx)
    np.testing.assert_allclose(physics, base.predict(tx, rx), atol=1e-9)
    np.testing.assert_allclose(load_model(read_artifact(saved, "rf")).predict(tx, rx), full, atol=1e-9)
    # the hand-made terms differ from zero on each link kind: a device's pattern + field + kriging, field alone
    assert np.all(np.abs(terms.apply_db(tx, rx)) > 1e-3)


def test_a_bad_residual_terms_setting_is_one_line_before_any_work(tmp_path):
    from typer.testing import CliRunner

    from rfir_cli.main import app

    from .helpers import write_measurements, write_scene

    write_scene(tmp_path / "scene.h5")
    write_measurements(tmp_path / "meas.h5")
    r = CliRunner().invoke(app, ["--set", "rf_fit.room.residual_terms=field+furniture", "rf-fit",
                                 str(tmp_path / "scene.h5"), str(tmp_path / "meas.h5"), "-o", str(tmp_path / "rf.h5")])
    assert r.exit_code == 4, r.output
    assert "rf_fit.room.residual_terms" in r.output and "furniture" in r.output and "Traceback" not in r.output
    assert "traced" not in r.output and not (tmp_path / "rf.h5").exists()
