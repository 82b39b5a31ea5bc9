"""Room geometry traced once, the frequency applied at evaluation (rfir_stages.model.room_paths.RoomPaths.at_frequency,
room_diffuse.DiffuseTerms.at_frequency, room.RoomLinks.at_frequency, RoomPredictor.predict_db).

- paths and diffuse terms traced at 2.4 GHz and evaluated at 5.8 GHz equal those traced at 5.8 GHz (specular field,
  diffuse power, the one-material form the |Gamma| ranges use);
- over a metal floor, paths traced at one frequency give the two-ray closed form at another;
- a model predicts only inside its material laws' range, with a one-line error naming the limiting law;
- `predict rssi --freqs` writes a column per frequency from one fit, the first the fitted frequency's prediction;
- slow (-m slow): a classroom simulated at 2.4 GHz and fitted there predicts the classroom simulated at 5.8 GHz
  within 1 dB of the model fitted at 5.8 GHz itself (the Sionna simulator, ITU materials at each frequency).
"""
import json
import math

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from rfir_cli.main import app
from rfir_core.artifacts import read_artifact
from rfir_core.errors import ConfigError
from rfir_core.physics.materials import C0, abs2
from rfir_stages.model.physical import MaterialParams
from rfir_stages.model.room import MaterialPart, RoomPredictor, band_of

from .helpers import links as grid_links
from .helpers import metal_floor_paths, room_geometry, write_measurements, write_scene


@pytest.fixture(scope="module")
def room():
    return room_geometry(spacing_m=0.3)[0]


def test_links_evaluated_at_a_frequency_equal_links_traced_there(room):
    tx, rx, ti, ri = grid_links()
    t, r = tx[ti], rx[ri]
    vals = MaterialParams(room.num_materials, eps_r=4.0, sigma_1ghz=0.05, scattering=0.3, thickness_m=0.12).values()
    with torch.no_grad():
        low = room.links(t, r, np.full(len(t), 2.4e9))
        high = room.links(t, r, np.full(len(t), 5.8e9))
        moved = low.at_frequency(5.8e9)
        assert moved.paths.num == high.paths.num and moved.diffuse is not None
        # the specular field, every coefficient exact (RoomPaths.field), and the tabulated fit form with diffuse
        eta = vals.eta(torch.tensor([5.8e9], dtype=torch.float64))[torch.as_tensor(room.material_of_patch)]
        th = vals.thickness_m[torch.as_tensor(room.material_of_patch)]
        s = vals.scattering[torch.as_tensor(room.material_of_patch)]
        np.testing.assert_allclose(moved.paths.field(eta, th, s).numpy(), high.paths.field(eta, th, s).numpy(),
                                   rtol=1e-12)
        got, want = moved.power(vals)[:, 0].numpy(), high.power(vals)[:, 0].numpy()
        np.testing.assert_allclose(got, want, rtol=1e-12)
        np.testing.assert_allclose(moved.diffuse.power(vals.eta(torch.tensor([5.8e9], dtype=torch.float64)),
                                                       vals.thickness_m, vals.scattering).numpy(),
                                   high.diffuse.power(vals.eta(torch.tensor([5.8e9], dtype=torch.float64)),
                                                      vals.thickness_m, vals.scattering).numpy(), rtol=1e-12)
        # the frequency did change what was evaluated: the unobstructed direct paths' power by the free-space loss
        # alone, (5.8 / 2.4)^2 (7.7 dB), the total by other amounts (interference, the materials' coefficients)
        clear = (moved.paths.order == 0) & (moved.paths.kind == 0).all(1)
        seen = torch.zeros(len(t), dtype=torch.bool).index_fill(0, moved.paths.link[clear], True).numpy()
        assert seen.sum() >= 10
        ratio = (abs2(low.select_paths(clear).components(vals)[0])
                 / abs2(moved.select_paths(clear).components(vals)[0])).numpy()
        np.testing.assert_allclose(ratio[seen], (5.8 / 2.4) ** 2, rtol=1e-9)
        assert np.abs(10 * np.log10(got / low.power(vals)[:, 0].numpy())).max() > 3.0
        # the one-material form the |Gamma| ranges evaluate (its diffuse part carries lambda^2 too)
        part = MaterialPart(moved, 0, vals)
        np.testing.assert_allclose(part.power(vals).numpy(), want[part.rows.numpy()], rtol=1e-9)
        # and back: the 2.4 GHz links rebuilt from the 5.8 GHz ones
        np.testing.assert_allclose(high.at_frequency(2.4e9).power(vals)[:, 0].numpy(),
                                   low.power(vals)[:, 0].numpy(), rtol=1e-12)
        # a band's channels from one trace equal each channel traced on its own
        band = band_of(low, "ble", 5.0e9, fitted_hz=2.44e9)
        each = [room.links(t, r, np.full(len(t), f)).power(vals)[:, 0].numpy()
                for f in (2.402e9 + 2.56e9, 2.426e9 + 2.56e9, 2.480e9 + 2.56e9)]
        np.testing.assert_allclose(band.power(vals)[:, 0].numpy(), np.mean(each, 0), rtol=1e-12)


def test_metal_floor_paths_traced_at_one_frequency_give_the_two_ray_form_at_another():
    tx, rx, paths, n_patches = metal_floor_paths(40, 2.4e9)
    metal = torch.full((n_patches, 1), complex(1.0, -math.inf), dtype=torch.complex128)
    s0 = torch.zeros(n_patches, dtype=torch.float64)
    d0 = np.linalg.norm(rx - tx, axis=1)
    d1 = np.linalg.norm(rx - tx * [1, 1, -1], axis=1)
    for f in (2.4e9, 5.8e9, 28e9):
        lam, k = C0 / f, 2 * math.pi * f / C0
        field = paths.at_frequency(f).field(metal, None, s0).numpy()
        # H polarisation: TE off the floor, R = -1 on metal
        np.testing.assert_allclose(field, lam / (4 * math.pi) * (np.exp(-1j * k * d0) / d0 - np.exp(-1j * k * d1) / d1),
                                   rtol=1e-9)


def test_prediction_frequencies_inside_the_material_laws_range_only():
    pred = RoomPredictor.__new__(RoomPredictor)        # the range depends on the materials' laws alone
    pred.freq_hz, pred.tabulated = 2.4e9, ["", "concrete", ""]
    assert pred.frequency_range_hz()[:2] == (1e9, 100e9)
    np.testing.assert_array_equal(pred.check_frequencies([2.4e9, 5.8e9]), [2.4e9, 5.8e9])
    pred.tabulated = ["", "brick", "marble"]             # ITU-R P.2040: brick 1-40 GHz, marble 1-60 GHz
    lo, hi, why = pred.frequency_range_hz()
    assert (lo, hi) == (1e9, 40e9) and "brick" in why
    for bad in (0.5e9, 50e9, float("nan")):
        with pytest.raises(ConfigError) as err:
            pred.check_frequencies([2.4e9, bad])
        assert "\n" not in str(err.value) and "1-40 GHz" in str(err.value)


def test_predict_rssi_at_several_frequencies_from_one_fit(tmp_path):
    write_scene(tmp_path / "scene.h5", spacing_m=0.3)
    write_measurements(tmp_path / "meas.h5")
    fast = ["--set", "rf_fit.physical.iterations=30", "--set", "rf_fit.physical.start_iterations=10",
            "--set", "rf_fit.room.starts_kept=1", "--set", "rf_fit.room.reflection_ranges=false"]
    run = lambda *a: CliRunner().invoke(app, [str(x) for x in a])  # noqa: E731
    r = run(*fast, "rf-fit", tmp_path / "scene.h5", tmp_path / "meas.h5", "-o", tmp_path / "rf.h5")
    assert r.exit_code == 0, r.output
    r = run("predict", "rssi", tmp_path / "rf.h5", "--measurements", tmp_path / "meas.h5", "-o", tmp_path / "p.h5")
    assert r.exit_code == 0, r.output
    assert "at 2.4 GHz (the frequency the model was fitted at; --freqs predicts at others)" in " ".join(r.output.split())
    r = run("predict", "rssi", tmp_path / "rf.h5", "--measurements", tmp_path / "meas.h5", "--freqs", "2.4e9,5.8e9",
            "-o", tmp_path / "p2.h5")
    assert r.exit_code == 0, r.output
    one, two = read_artifact(tmp_path / "p.h5", "predictions"), read_artifact(tmp_path / "p2.h5", "predictions")
    np.testing.assert_array_equal(np.asarray(two["freq_hz"]), [2.4e9, 5.8e9])
    got = np.asarray(two["path_gain_db"])
    np.testing.assert_allclose(got[:, 0], np.asarray(one["path_gain_db"])[:, 0], atol=1e-9)
    # the 5.8 GHz column is the model's prediction there (the same materials, the paths evaluated at 5.8 GHz)
    model = RoomPredictor(read_artifact(tmp_path / "rf.h5", "rf"))
    meas = read_artifact(tmp_path / "meas.h5", "measurements")
    want = model.predict_db(np.asarray(meas["tx_pos"]), np.asarray(meas["rx_pos"]), [5.8e9])[:, 0]
    np.testing.assert_allclose(got[:, 1], want, atol=1e-9)
    assert np.median(got[:, 0] - got[:, 1]) > 3.0          # most of 20 log10(5.8 / 2.4) = 7.7 dB of free space
    r = run("predict", "rssi", tmp_path / "rf.h5", "--measurements", tmp_path / "meas.h5", "--freqs", "200e9",
            "-o", tmp_path / "p3.h5")
    assert r.exit_code != 0 and "200 GHz is outside 1-100 GHz" in " ".join(r.output.split())
    assert not (tmp_path / "p3.h5").exists()


@pytest.mark.slow
def test_classroom_fitted_at_2g4_predicts_5g8_within_1_db_of_a_fit_there(tmp_path):
    pytest.importorskip("sionna.rt")
    run = lambda *a: CliRunner().invoke(app, [str(x) for x in a])  # noqa: E731
    fast = ["--set", "rf_fit.physical.iterations=120", "--set", "rf_fit.physical.start_iterations=30"]
    for ghz in ("2.4", "5.8"):
        r = run("--set", f"simulate.rssi.freqs_hz=[{ghz}e9]", "simulate", "classroom", tmp_path / f"sim{ghz}",
                "--quick", "--no-photos")
        assert r.exit_code == 0, r.output
    r = run("mesh-gaussians", tmp_path / "sim2.4/meshes/classroom_gt.ply", "-o", tmp_path / "scene.h5", "--preset",
            "room")
    assert r.exit_code == 0, r.output
    mae = {}
    for ghz in ("2.4", "5.8"):
        r = run(*fast, "rf-fit", tmp_path / "scene.h5", tmp_path / f"sim{ghz}/measurements.h5", "-o",
                tmp_path / f"rf{ghz}.h5")
        assert r.exit_code == 0, r.output
    for name, rf in (("moved", "rf2.4.h5"), ("own", "rf5.8.h5")):
        res = tmp_path / f"{name}.json"
        r = run("predict", "rssi", tmp_path / rf, "--measurements", tmp_path / "sim5.8/measurements.h5", "--freqs",
                "5.8e9", "-o", tmp_path / f"{name}.h5", "--results", res)
        assert r.exit_code == 0, r.output
        mae[name] = json.loads(res.read_text())["metrics"]["mae_db"]
    assert mae["moved"] <= mae["own"] + 1.0, mae
