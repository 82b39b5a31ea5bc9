"""The free fit keeps its best state, floors its predictions, validates small sets on enough links,
and records the wall time of the whole command."""
import math
import time

import numpy as np
import pytest
import torch

from rfir_cli.artifacts import read_artifact
from rfir_cli.errors import InputFileError
from rfir_stages.geom import gaussians_from_mesh, write_scene_artifact
from rfir_stages.model.predict import FLOOR_DB
from rfir_stages.rf_fit.antennas import AntennaPattern
from rfir_stages.rf_fit.fit import FitConfig, fit, floored, loss_fn, predict_db
from rfir_stages.rf_fit.params import RFParams
from rfir_stages.rf_fit.render import Materials, RenderSettings, build_cache, render, render_power
from rfir_stages.rf_fit.splits import KFOLD_MAX_LINKS, MIN_VALIDATION_LINKS, validation_folds

from .helpers import DEG, box_fields, db, geometry, radar, square

ISO = AntennaPattern("isotropic")


def _box_problem(step_deg: float = 10.0):
    """A box with random per-Gaussian materials, monostatic links every `step_deg` over half a turn."""
    geom = geometry(box_fields(0.06, 0.03))
    g = geom.num
    gen = torch.Generator().manual_seed(3)
    truth = Materials(torch.full((g,), 0.9, dtype=torch.float64),
                      1 + 4 * torch.rand(g, generator=gen, dtype=torch.float64),
                      torch.polar(0.3 + 0.6 * torch.rand(g, generator=gen, dtype=torch.float64),
                                  2 * math.pi * torch.rand(g, generator=gen, dtype=torch.float64)))
    aspects = np.arange(0, 180, step_deg) * DEG + 0.05
    return geom, truth, aspects


def _loss(cache, params, meas) -> float:
    with torch.no_grad():
        return float(loss_fn(predict_db(cache, params), torch.as_tensor(meas), "db_mse"))


def test_predictions_of_a_link_that_sees_nothing_sit_at_the_floor_and_are_counted():
    v, f = square(0.2)                                   # a plate in the plane x = 0, seen edge-on from +y
    geom = geometry(gaussians_from_mesh(v, f, 0.04))
    links = radar(np.array([0.0, -90.0]) * DEG, 3.0, [2.4e9], separation_m=0.0)
    cache = build_cache(geom, links, ISO, ISO, None, RenderSettings(visibility=False))
    params = RFParams(torch.arange(geom.num), 1, diffuse=0.1)
    power = render_power(cache, params.materials()).detach()
    assert power[1, 0] < 1e-100                          # the renderer's edge-on power: ~1e-123
    pred = predict_db(cache, params).detach()
    assert pred[1, 0] == pytest.approx(FLOOR_DB, abs=1e-6)   # never -1200 dB in a dB loss or metric
    assert pred[0, 0] == pytest.approx(10 * np.log10(float(power[0, 0])), abs=1e-6)   # seen links untouched
    assert floored(cache, params) == 1


def test_a_warm_started_fit_never_ends_worse_than_it_started():
    """A step size that throws the state away: the fit keeps the best state (here its start)."""
    geom, truth, aspects = _box_problem()
    cache = build_cache(geom, radar(aspects, 2.5, [2.4e9], height_m=0.02), ISO, ISO, None,
                        RenderSettings(visibility=False))
    meas = db(render(cache, truth))
    params = RFParams(torch.arange(geom.num), 1, opacity=0.9, roughness=2.0, gamma_abs=0.5)
    fit(cache, meas, params, FitConfig(iterations=40, lr=0.5))
    start = _loss(cache, params, meas)
    res = fit(cache, meas, params, FitConfig(iterations=10, lr=5.0, s_tx_lr=20.0), init_gain=False)
    assert res.loss_curve[0] == pytest.approx(start) and res.loss_curve[1:].min() > 10 * start  # it did diverge
    assert _loss(cache, params, meas) <= start + 1e-12 and res.extra["best_step"] == 0
    assert res.train_mae_db == pytest.approx(res.initial_mae_db)


def test_model_selection_fits_keep_the_state_of_lowest_validation_mae():
    """Validation beyond the training aspects (an extrapolation): fitting on longer overfits, the fit
    keeps the earlier state that predicted the held-out links best, not the last step."""
    geom, truth, aspects = _box_problem(5.0)
    train, val = np.flatnonzero(aspects < 1.2), np.flatnonzero(aspects >= 1.2)
    settings = RenderSettings(visibility=False)
    cache_tr = build_cache(geom, radar(aspects[train], 2.5, [2.4e9], height_m=0.02), ISO, ISO, None, settings)
    cache_val = build_cache(geom, radar(aspects[val], 2.5, [2.4e9], height_m=0.02), ISO, ISO, None, settings)
    meas_tr, meas_val = db(render(cache_tr, truth)), db(render(cache_val, truth))
    cfg = FitConfig(iterations=80, lr=0.3)
    last = RFParams(torch.arange(geom.num), 1, opacity=0.9, roughness=2.0, gamma_abs=0.5)
    fit(cache_tr, meas_tr, last, cfg)
    kept = RFParams(torch.arange(geom.num), 1, opacity=0.9, roughness=2.0, gamma_abs=0.5)
    res = fit(cache_tr, meas_tr, kept, cfg, validation=(cache_val, meas_val), eval_every=1)

    def val_mae(p):
        with torch.no_grad():
            return float((predict_db(cache_val, p) - torch.as_tensor(meas_val)).abs().mean())

    assert res.extra["best_step"] < cfg.iterations // 2
    assert val_mae(kept) == pytest.approx(res.extra["val_mae_db"])
    assert val_mae(kept) < val_mae(last) - 0.05   # 2.45 dB against 2.57 dB at the last step


def test_validation_folds_hold_out_enough_links_when_they_can():
    m = 36                                   # every 10th row: 4 links; 3 interleaved folds: all 36
    folds, how = validation_folds("data", np.arange(m) * 10.0, np.full(m, 3.0))
    assert len(folds) == 3 and sorted(np.concatenate(folds).tolist()) == list(range(m)) and "3-fold" in how
    big = 10 * MIN_VALIDATION_LINKS          # every 10th row is enough: one fold
    folds, _ = validation_folds("every-2", np.arange(big) * 0.5, np.full(big, 3.0))
    assert len(folds) == 1 and len(folds[0]) == MIN_VALIDATION_LINKS
    mid = KFOLD_MAX_LINKS + 30               # too many for k-fold: a larger share, every 3rd row
    folds, _ = validation_folds("data", np.arange(mid) * 1.0, np.full(mid, 3.0))
    assert len(folds) == 1 and len(folds[0]) == mid // 3
    rng = np.repeat([2.0, 3.0, 4.0], 12)     # range protocol: each training range in turn
    folds, how = validation_folds("range:5", np.tile(np.arange(12) * 30.0, 3), rng)
    assert [sorted(set(rng[f])) for f in folds] == [[2.0], [3.0], [4.0]]
    deg = np.arange(0, 360, 4.0)
    deg = deg[(deg < 45) | (deg >= 135)]     # sector:45:135 held out; the rows next to it validate
    folds, _ = validation_folds("sector:45:135", deg, np.full(len(deg), 3.0))
    near = deg[folds[0]]
    assert len(folds) == 1 and len(near) == min(MIN_VALIDATION_LINKS, len(deg) // 3)
    gap = np.minimum(np.mod(deg - 135, 360), np.mod(45 - deg, 360))
    assert gap[folds[0]].max() <= np.sort(gap)[len(near) - 1]


def test_wall_time_covers_the_whole_command_with_its_parts(tmp_path):
    from rfir_stages.rf_fit import run

    from .test_stage import _scattering_measurements

    fields = box_fields(0.06, 0.03)
    write_scene_artifact(tmp_path / "scene.h5", fields)
    meas = _scattering_measurements(tmp_path / "m.h5", fields, True)
    began = time.time() - 5.0                # the command began 5 s before the stage (imports, parsing)
    res = run(tmp_path / "scene.h5", meas, tmp_path / "rf.h5",
              {"visibility": False, "iterations": 20, "checkpoint_every": 0, "scattering": "auto",
               "sharing": "gaussian", "model": "free"}, t_start=began)
    attrs = read_artifact(tmp_path / "rf.h5", "rf").free["training@attrs"]
    parts = attrs["trace_time_s"] + attrs["select_time_s"] + attrs["refit_time_s"]
    assert attrs["wall_time_s"] >= 5.0 + parts - 1e-6 and res.wall_time_s >= attrs["wall_time_s"]
    assert attrs["select_time_s"] > 0 and attrs["refit_time_s"] > 0
    cands = attrs["scattering_fit_time_coherent_s"] + attrs["scattering_fit_time_incoherent_s"]
    assert 0 < cands <= attrs["select_time_s"]
    assert set(res.timings_s) >= {"trace", "select", "fit", "total"}


def test_resume_reuses_the_model_selection_of_the_interrupted_run(tmp_path):
    from rfir_cli.progress import NullProgress
    from rfir_stages.rf_fit import run

    from .test_stage import _scattering_measurements

    class Logged(NullProgress):
        def __init__(self):
            self.lines = []

        def log(self, message: str) -> None:
            self.lines.append(message)

    fields = box_fields(0.06, 0.03)
    write_scene_artifact(tmp_path / "scene.h5", fields)
    meas = _scattering_measurements(tmp_path / "m.h5", fields, True)
    cfg = {"visibility": False, "iterations": 10, "checkpoint_every": 5, "scattering": "auto",
           "sharing": "gaussian", "model": "free"}
    first = run(tmp_path / "scene.h5", meas, tmp_path / "rf.h5", cfg)
    assert (tmp_path / "rf.h5.ckpt.pt.selection").exists()
    log = Logged()
    again = run(tmp_path / "scene.h5", meas, tmp_path / "rf.h5", dict(cfg, iterations=12), resume=True, progress=log)
    assert any("model selection reused" in line for line in log.lines), log.lines
    assert not any("validation MAE on" in line for line in log.lines)          # no candidate was fitted again
    assert again.scattering["selected"] == first.scattering["selected"]
    assert again.scattering["val_mae_coherent_db"] == first.scattering["val_mae_coherent_db"]
    assert read_artifact(tmp_path / "rf.h5", "rf").free["training@attrs"]["resumed_at"] == 10
    other = Logged()                            # other settings: selected afresh, then the checkpoint is refused
    with pytest.raises(InputFileError, match="other inputs or settings"):
        run(tmp_path / "scene.h5", meas, tmp_path / "rf.h5", dict(cfg, lr=0.2), resume=True, progress=other)
    assert any("validation MAE on" in line for line in other.lines)
