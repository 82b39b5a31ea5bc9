"""End to end on a tiny Sionna data set: surfels from the mesh, rf-fit, predict rcs (slow: Sionna)."""
import numpy as np
import pytest

from rfir_core.artifacts import read_artifact
from rfir_core.config import resolve_config


@pytest.mark.slow
def test_fit_on_simulated_lego_runs_end_to_end_and_lowers_its_training_error(tmp_path):
    """Sionna data -> surfels -> rf-fit -> predict rcs. Beating the nearest aspect is not asserted here:
    Sionna's RCS of a small object is geometric optics plus diffuse scattering, which surfel physical
    optics does not reproduce (docs/results.md, the rcs table; measured here at 15 deg steps: 14.9 dB
    against nearest aspect 14.6); RCS physics is judged on physical-optics data
    (tests/rf_fit/test_physical_fit.py)."""
    pytest.importorskip("sionna.rt")
    from rfir_stages.geom import scene_from_mesh, write_scene_artifact
    from rfir_stages.predict import run_rcs
    from rfir_stages.rf_fit import run as rf_fit
    from rfir_stages.simulate import run as simulate

    cfg = resolve_config(None, [], None)
    sim = dict(cfg["simulate"], photos=False, tasks=["rcs"])
    sim["rcs"] = dict(sim["rcs"], freqs_hz=[2.4e9], ranges_m=[3.0], aspect_step_deg=15.0, samples_per_src=10000)
    simulate("lego", tmp_path / "sim", sim, quick=False)
    fields, names = scene_from_mesh("lego", 0.03)
    write_scene_artifact(tmp_path / "scene.h5", fields, label_names=names)
    fit_cfg = dict(cfg["rf_fit"], physical=dict(cfg["rf_fit"]["physical"], iterations=200))
    fit = rf_fit(tmp_path / "scene.h5", tmp_path / "sim" / "measurements.h5", tmp_path / "rf.h5", fit_cfg)
    assert fit.train_mae_db < fit.initial_mae_db, fit                  # the materials were fitted
    res = run_rcs(tmp_path / "rf.h5", tmp_path / "pred.h5", cfg["predict"],
                  measurements_path=tmp_path / "sim" / "measurements.h5", results_path=tmp_path / "r.json")
    m = res.metrics
    assert m["num_test"] == 12
    assert np.isfinite(m["mae_db"]) and m["mae_train_db"] < m["mae_db"], m
    assert np.isfinite(read_artifact(tmp_path / "pred.h5", "predictions").data["rcs_dbsm"]).all()
