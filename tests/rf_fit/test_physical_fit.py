"""`rfir rf-fit` with the physical model, `rfir predict rcs` at a frequency never fitted, and `rfir check`."""
import math
import shutil

import h5py
import numpy as np
import pytest

from rfir_core.artifacts import read_artifact, validate_artifact
from rfir_core.progress import NullProgress
from rfir_stages.geom import write_scene_artifact
from rfir_stages.geom.from_mesh import gaussians_from_mesh
from rfir_core.physics.materials import C0, fresnel, itu_law, permittivity
from rfir_stages.simulate.scenes import box

from .helpers import po_measurements


@pytest.fixture(scope="module")
def metal_box(tmp_path_factory):
    d = tmp_path_factory.mktemp("metal_box")
    v, f = box((-0.08, -0.05, -0.06), (0.08, 0.05, 0.06))
    po_measurements(d / "meas.h5", v, f, np.array(["metal"] * len(f)), np.full(len(f), 0.003),
                     [2.4e9, 5.8e9], np.arange(0, 360, 4.0))
    fields = gaussians_from_mesh(v, f, 0.012, labels=np.zeros(len(f), dtype=np.int64))
    write_scene_artifact(d / "scene.h5", fields)
    return d


def test_physical_fit_finds_metal_and_predicts_an_unfitted_frequency(metal_box, tmp_path):
    from rfir_stages.predict.rcs import run_rcs
    from rfir_stages.rf_fit import run

    d = metal_box
    cfg = {"antenna": "isotropic", "freqs_hz": [2.4e9],
           "physical": {"sharing": "global", "iterations": 120, "start_iterations": 30, "edge_waves": "off"}}
    res = run(d / "scene.h5", d / "meas.h5", tmp_path / "rf.h5", cfg)
    assert res.selection["sharing_selected"] == "global"
    assert res.materials[0]["gamma_normal_abs"][0] > 0.9                 # metal recognised as metal
    rf = read_artifact(tmp_path / "rf.h5", "rf")
    assert validate_artifact(tmp_path / "rf.h5") == []                  # `rfir check` passes
    assert np.all(np.asarray(rf["rf/gamma_abs"]) > 0.9)                 # attribute maps show the fitted value
    assert rf.free["model@attrs"]["family"] == "physical"
    # the links pin a metal box's material: its |Gamma(0)| range is narrow, stays metal, holds the fitted value
    lo, hi = np.asarray(rf["material/gamma_normal_range"])[0]
    fitted = res.materials[0]["gamma_normal_abs"][0]
    assert lo <= fitted <= hi and lo > 0.85 and res.materials[0]["gamma_normal_range"] == [lo, hi]
    from typer.testing import CliRunner

    from rfir_cli.main import app
    shown = CliRunner().invoke(app, ["info", str(tmp_path / "rf.h5")])
    assert shown.exit_code == 0 and "|Gamma(0)| range" in shown.output and f"{lo:.2f}-{hi:.2f}" in shown.output
    assert "not determined by the links" not in shown.output
    # fitted at 2.4 GHz only; predicted at 5.8 GHz on the odd aspects, against the PO data there
    out = run_rcs(tmp_path / "rf.h5", tmp_path / "p.h5", {"occlusion": "auto"}, measurements_path=d / "meas.h5",
                  freqs_hz=[5.8e9], results_path=tmp_path / "r.json")
    assert out.freqs_hz == [5.8e9]
    assert out.metrics["mae_db"] < 3.0, out.metrics
    assert res.train_mae_db < 2.0
    # one material: no word about carrying materials to another frequency; two fitted at one: a warning
    assert not any("carry over" in m for m in _predict_log(tmp_path / "rf.h5"))
    two = tmp_path / "rf_two.h5"
    shutil.copy(tmp_path / "rf.h5", two)
    with h5py.File(two, "r+") as h:
        for key in ("eps_r", "sigma_1ghz_s_per_m", "scattering", "thickness_m", "gamma_normal_abs",
                    "gamma_normal_range"):
            val = h[f"material/{key}"][...]
            del h[f"material/{key}"]
            h[f"material/{key}"] = np.concatenate([val, val])
        h["model"].attrs["material_names"] = np.array(["a", "b"], dtype=object)
    assert any("carry over" in m for m in _predict_log(two))


def _predict_log(path) -> list[str]:
    """predict_physical_db's log lines for two links at 5.8 GHz."""
    from rfir_stages.model.predict import predict_physical_db

    class Recorder(NullProgress):
        lines: list = []

        def log(self, message: str) -> None:
            self.lines.append(message)

    rec = Recorder()
    rec.lines = []
    tx = np.array([[2.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    predict_physical_db(read_artifact(path, "rf"), tx, tx, [5.8e9], "rcs", progress=rec)
    return rec.lines


def test_sharing_auto_offers_per_class_and_global_and_records_the_choice(tmp_path):
    """Two unnamed labels (the box's two halves; a class each): auto fits one material per class and one
    for the scene on the same validation rows and records both MAEs and the choice in the artifact."""
    from rfir_stages.rf_fit import run

    v, f = box((-0.08, -0.05, -0.06), (0.08, 0.05, 0.06))
    po_measurements(tmp_path / "meas.h5", v, f, np.array(["metal"] * len(f)), np.full(len(f), 0.003), [2.4e9],
                    np.arange(0, 360, 6.0))
    labels = (v[f].mean(1)[:, 0] > 0).astype(np.int64)
    write_scene_artifact(tmp_path / "scene.h5", gaussians_from_mesh(v, f, 0.02, labels=labels))
    cfg = {"antenna": "isotropic", "visibility": False,
           "physical": {"iterations": 40, "start_iterations": 10, "residual": "off", "edge_waves": "off"}}
    res = run(tmp_path / "scene.h5", tmp_path / "meas.h5", tmp_path / "rf.h5", cfg)
    keys = {k for k in res.selection if k.startswith("val_mae_")}
    assert keys == {"val_mae_class_db", "val_mae_global_db"}, res.selection
    score = {s: res.selection[f"val_mae_{s}_db"] for s in ("class", "global")}
    best = min(score, key=score.get)               # one material wins also within one standard error of it
    expected = "global" if score["global"] <= score[best] + res.selection["validation_se_db"] else best
    assert res.selection["validation_se_db"] > 0 and res.selection["sharing_selected"] == expected
    attrs = read_artifact(tmp_path / "rf.h5", "rf").free["training@attrs"]
    assert attrs["selection_sharing_selected"] == expected and attrs["sharing"] == expected
    assert attrs["selection_validation_se_db"] == res.selection["validation_se_db"]


def test_bad_physical_settings_are_config_errors(metal_box, tmp_path):
    from rfir_core.errors import ConfigError
    from rfir_stages.rf_fit import run

    for cfg, msg in (({"physical": {"sharing": "brick"}}, "rf_fit.physical.sharing"),
                     ({"physical": {"polarisation": "X"}}, "polarisation"),
                     ({"physical": {"selection": "best"}}, "rf_fit.physical.selection"),
                     ({"loss": "paper"}, "rf_fit.loss")):
        with pytest.raises(ConfigError, match=msg):
            run(metal_box / "scene.h5", metal_box / "meas.h5", tmp_path / "rf.h5", {"antenna": "isotropic", **cfg})
    assert not (tmp_path / "rf.h5").exists()


def test_truth_material_reproduces_the_po_simulator(metal_box):
    """No fitting: the surfel model with the simulator's material against the simulator's data."""
    import torch

    from rfir_stages.model.physical import MaterialParams, PairSettings, build_pairs, scattered_power
    from rfir_stages.model.antenna_patterns import AntennaPattern
    from rfir_stages.model.links import geometry_from_artifact, make_links, scene_centre
    from rfir_stages.model.occlusion import make_provider

    scene, meas = read_artifact(metal_box / "scene.h5", "scene"), read_artifact(metal_box / "meas.h5", "measurements")
    geom = geometry_from_artifact(scene)
    freqs = np.asarray(meas["freq_hz"])
    links = make_links(meas["tx_pos"], meas["rx_pos"], freqs, scene_centre(geom), "rcs")
    iso = AntennaPattern("isotropic")
    pairs = build_pairs(geom, links, iso, iso, make_provider("auto", geom), PairSettings())
    eps, sig = itu_law("metal", 1e9)
    mats = MaterialParams(1, eps_r=1.0, sigma_1ghz=1e7, scattering=1e-9, thickness_m=0.003, sigma_exponent=0.0)
    pred = 10 * np.log10(scattered_power(pairs, torch.zeros(geom.num, dtype=torch.int64), mats.values()).detach().numpy())
    err = np.abs(pred - np.asarray(meas["path_gain_db"]))
    assert np.median(err) < 1.5, np.median(err, axis=0)
    k0 = 2 * math.pi * 2.4e9 / C0
    assert abs(fresnel(permittivity(eps, sig, 2.4e9), 1.0, k0, 0.003)[0].item()) > 0.999


def test_one_standard_error_rule_prefers_fewer_materials_only_within_the_noise():
    """The candidate with fewer materials wins when its validation MAE is within one standard error of the
    best's, and only then; among equal counts the lower score wins."""
    from rfir_stages.rf_fit.stage import one_standard_error_choice
    rng = np.random.default_rng(0)
    best_err = np.abs(rng.normal(0.0, 3.0, 12))                  # 12 held-out links: a noisy score
    se = best_err.std(ddof=1) / np.sqrt(best_err.size)
    scores = {"segment": best_err.mean(), "global": best_err.mean() + 0.5 * se, "global+edges": best_err.mean() + 0.9 * se}
    errors = {k: best_err for k in scores}
    materials = {"segment": 8, "global": 1, "global+edges": 1}
    chosen, best, got_se = one_standard_error_choice(scores, errors, materials)
    assert (chosen, best) == ("global", "segment") and math.isclose(got_se, se)
    scores["global"] = scores["global+edges"] = best_err.mean() + 1.5 * se    # outside the noise: the best
    assert one_standard_error_choice(scores, errors, materials)[0] == "segment"
    many = np.abs(rng.normal(0.0, 3.0, 2000))                    # many links: the same gap is outside one SE
    scores = {"segment": many.mean(), "global": many.mean() + 0.5 * se}
    assert one_standard_error_choice(scores, {k: many for k in scores}, materials)[0] == "segment"
