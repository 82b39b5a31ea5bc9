"""How a link's paths add up (rf_fit.room.band, rfir_stages.model.room.BANDS): coherent at one frequency,
averaged over the BLE advertising channels, or incoherent (the paths' powers).

- incoherent: over a metal floor, the power is |direct|^2 + |image|^2 of the closed form, with none of the
  coherent sum's interference nulls;
- ble: the power is the mean of three single-frequency evaluations, and differs from the one at 2.44 GHz;
- a model fitted with band "ble" stores it and predict rssi reproduces the band average;
- "auto" keeps rfir simulate's data coherent, and on measured data prints the validated choice.
"""
import math

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact
from rfir_cli.main import app
from rfir_core.physics.materials import C0
from rfir_stages.model.physical import MaterialParams
from rfir_stages.model.room import BLE_CHANNELS_HZ, BandLinks, RoomPredictor

from .helpers import links as grid_links
from .helpers import metal_floor_paths, room_geometry, write_measurements, write_scene

FAST = ["--set", "rf_fit.physical.iterations=30", "--set", "rf_fit.physical.start_iterations=10",
        "--set", "rf_fit.room.starts_kept=1", "--set", "rf_fit.room.reflection_ranges=false"]


def test_incoherent_power_of_a_metal_floor_is_the_sum_of_the_two_rays():
    f = 2.4e9
    lam, k = C0 / f, 2 * math.pi * f / C0
    tx, rx, paths, n_patches = metal_floor_paths(60, f)
    metal = torch.full((n_patches, 1), complex(1.0, -math.inf), dtype=torch.complex128)
    s0 = torch.zeros(n_patches, dtype=torch.float64)
    coherent = np.abs(paths.field(metal, None, s0).numpy()) ** 2
    incoherent = paths.field(metal, None, s0, incoherent=True).numpy()
    # H polarisation along y, perpendicular to the plane of incidence: TE, |R| = 1 on metal, e_T . e_R = 1
    d0 = np.linalg.norm(rx - tx, axis=1)
    d1 = np.linalg.norm(rx - tx * [1, 1, -1], axis=1)
    want = (lam / (4 * math.pi * d0)) ** 2 + (lam / (4 * math.pi * d1)) ** 2
    np.testing.assert_allclose(incoherent, want, rtol=1e-9)
    np.testing.assert_allclose(coherent, np.abs(lam / (4 * math.pi) * (np.exp(-1j * k * d0) / d0
                                                                          - np.exp(-1j * k * d1) / d1)) ** 2, rtol=1e-9)
    # the coherent sum has interference minima (it rises again with distance), the incoherent one falls steadily
    assert (np.diff(coherent) > 0).any() and (np.diff(incoherent) < 0).all()
    assert (10 * np.log10(incoherent / coherent)).max() > 10


@pytest.fixture(scope="module")
def room():
    return room_geometry(spacing_m=0.3)[0]


def _mats(n):
    p = MaterialParams(n, eps_r=4.0, sigma_1ghz=0.05, scattering=0.3, thickness_m=0.12)
    return p.values(), p


def test_ble_power_is_the_mean_of_the_three_channels(room):
    tx, rx, ti, ri = grid_links()
    t, r = tx[ti], rx[ri]
    vals, _ = _mats(room.num_materials)
    with torch.no_grad():
        band = room.band_links(t, r, 2.44e9, "ble")
        assert isinstance(band, BandLinks) and band.num_links == len(t)
        got = band.power(vals, 1.5)[:, 0].numpy()
        each = [room.links(t, r, np.full(len(t), f)).power(vals, 1.5)[:, 0].numpy() for f in BLE_CHANNELS_HZ]
        one = room.band_links(t, r, 2.44e9, "coherent").power(vals, 1.5)[:, 0].numpy()
        np.testing.assert_allclose(got, np.mean(each, 0), rtol=1e-12)
        assert np.abs(10 * np.log10(got / one)).max() > 0.5      # the band average is not one frequency's power
        # what the fit uses: a subset of links and of paths, as every channel's
        rows = torch.arange(0, len(t), 3)
        np.testing.assert_allclose(band.select_links(rows).power(vals)[:, 0].numpy(),
                                   np.mean(each, 0)[rows.numpy()] / 10 ** 0.15, rtol=1e-12)
        keep = band.paths.order < 2
        np.testing.assert_allclose(band.select_paths(keep).power(vals)[:, 0].numpy(), np.mean(
            [room.links(t, r, np.full(len(t), f)).select_paths(keep).power(vals)[:, 0].numpy()
             for f in BLE_CHANNELS_HZ], 0), rtol=1e-12)


def test_incoherent_links_sum_the_paths_powers(room):
    tx, rx, ti, ri = grid_links()
    t, r = tx[ti], rx[ri]
    vals, _ = _mats(room.num_materials)
    with torch.no_grad():
        coh = room.band_links(t, r, 2.4e9, "coherent")
        inc = room.band_links(t, r, 2.4e9, "incoherent")
        lab = coh.material_of_patch
        eta = vals.eta(torch.tensor([2.4e9]))[lab]
        spec = coh.paths.field(eta, vals.thickness_m[lab], vals.scattering[lab], incoherent=True).numpy()
        diff = coh.components(vals)[1].numpy()
        np.testing.assert_allclose(inc.power(vals)[:, 0].numpy(), spec + diff, rtol=1e-3)  # tables vs exact
        assert not np.allclose(inc.power(vals).numpy(), coh.power(vals).numpy(), rtol=1e-2)
        assert inc.select_links(torch.arange(5)).incoherent and inc.select_paths(inc.paths.order < 2).incoherent
        with pytest.raises(ValueError):
            inc.material_part(0, vals)


def _fit(d, name, *extra, simulated=True):
    write_scene(d / "scene.h5", spacing_m=0.3)
    write_measurements(d / "meas.h5", simulated=simulated)
    r = CliRunner().invoke(app, [*FAST, *extra, "rf-fit", str(d / "scene.h5"), str(d / "meas.h5"),
                                 "-o", str(d / name)])
    assert r.exit_code == 0, r.output
    return " ".join(r.output.split())


def test_a_ble_model_stores_its_band_and_predicts_the_band_average(tmp_path):
    out = _fit(tmp_path, "rf.h5", "--set", "rf_fit.room.band=ble")
    assert "band: ble (rf_fit.room.band)" in out
    rf = read_artifact(tmp_path / "rf.h5", "rf")
    assert rf.free["model@attrs"]["room.band"] == "ble"
    model = RoomPredictor(rf)
    assert model.room.settings.band == "ble"
    meas = read_artifact(tmp_path / "meas.h5", "measurements")
    t, r = np.asarray(meas["tx_pos"])[:20], np.asarray(meas["rx_pos"])[:20]
    got = model.path_gain_db(t, r)
    with torch.no_grad():
        each = [model.room.links(t, r, np.full(len(t), f)).power(model.mats, model.gain_db)[:, 0].numpy()
                for f in BLE_CHANNELS_HZ]
    np.testing.assert_allclose(got, 10 * np.log10(np.mean(each, 0)), atol=1e-9)
    # predict rssi writes the same
    r2 = CliRunner().invoke(app, ["predict", "rssi", str(tmp_path / "rf.h5"), "--measurements",
                                  str(tmp_path / "meas.h5"), "-o", str(tmp_path / "p.h5")])
    assert r2.exit_code == 0, r2.output


def test_auto_keeps_simulated_data_coherent(tmp_path):
    out = _fit(tmp_path, "rf.h5")
    assert "band: coherent (auto: simulated at one frequency)" in out and "validate the sums" not in out
    assert read_artifact(tmp_path / "rf.h5", "rf").free["model@attrs"]["room.band"] == "coherent"


def test_auto_on_measured_data_prints_each_sums_validation_mae(tmp_path):
    out = _fit(tmp_path, "rf.h5", "--set", "rf_fit.room.device_gains=off", simulated=False)
    assert "validate the sums" in out and "band: " in out
    assert "materials held fixed and the system gain refitted for each sum (MAE dB: coherent" in out
    band = read_artifact(tmp_path / "rf.h5", "rf").free["model@attrs"]["room.band"]
    assert band in ("coherent", "ble", "incoherent") and f"band: {band} (auto: measured data" in out


def test_an_unknown_band_is_refused(tmp_path):
    write_scene(tmp_path / "scene.h5", spacing_m=0.3)
    write_measurements(tmp_path / "meas.h5")
    r = CliRunner().invoke(app, ["--set", "rf_fit.room.band=wideband", "rf-fit", str(tmp_path / "scene.h5"),
                                 str(tmp_path / "meas.h5"), "-o", str(tmp_path / "rf.h5")])
    assert r.exit_code != 0 and "rf_fit.room.band" in r.output
