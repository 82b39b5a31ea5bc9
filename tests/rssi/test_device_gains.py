"""Per-device gains of the physical room model (stages/model/device_gains.py, docs/physics.md 8.11)."""
import json

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact
from rfir_cli.main import app
from rfir_stages.model.device_gains import DeviceGains, gains_at

from .helpers import links, write_measurements, write_scene

TX_GAIN_DB = np.array([4.0, -3.0, 1.5, -2.5])


def test_the_prior_shrinks_each_gain_as_ridge_regression_does():
    """With the residual variance s^2 fixed, minimising mean (g[i] - y)^2 + s^2/p^2/M sum g^2 gives
    g_d = sum_{i in d} y_i / (n_d + s^2/p^2) per device (closed form)."""
    tx = np.repeat(np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]]), [2, 5, 20], axis=0)
    rx = np.zeros_like(tx)
    y = torch.as_tensor(np.concatenate([np.full(2, 3.0), np.full(5, -2.0), np.full(20, 1.0)]))[:, None]
    dev = DeviceGains("tx", tx, rx, prior_db=2.0)
    s2 = torch.tensor(4.0)
    opt = torch.optim.LBFGS(list(dev.gains.values()), max_iter=200, line_search_fn="strong_wolfe")

    def closure():
        opt.zero_grad()
        loss = ((dev.link_db() - y) ** 2).mean() + dev.penalty(s2, len(y))
        loss.backward()
        return loss

    opt.step(closure)
    lam = 4.0 / 2.0 ** 2
    want = np.array([2 * 3.0 / (2 + lam), 5 * -2.0 / (5 + lam), 20 * 1.0 / (20 + lam)])
    np.testing.assert_allclose(dev.gains["tx"].detach().numpy(), want, atol=1e-3)
    assert abs(want[0]) < 3.0 * 0.7          # a device seen twice is pulled well toward 0


def test_gains_apply_by_position_and_unseen_devices_get_none():
    table = {"device_tx_pos_m": np.array([[0.0, 0, 1], [1, 0, 1]]), "device_tx_gain_db": np.array([2.0, -1.0]),
             "device_rx_pos_m": np.array([[5.0, 5, 1]]), "device_rx_gain_db": np.array([0.5])}
    tx = np.array([[0.0, 0, 1], [1.0002, 0, 1], [3, 3, 3]])       # the second within 1 mm of a fitted Tx
    rx = np.array([[5.0, 5, 1], [9, 9, 9], [5, 5, 1]])
    got, matched = gains_at(table, tx, rx)
    np.testing.assert_allclose(got, [2.5, -1.0, 0.5])
    assert matched == 4


@pytest.fixture(scope="module")
def with_gains(tmp_path_factory):
    d = tmp_path_factory.mktemp("devices")
    write_scene(d / "scene.h5", spacing_m=0.3)
    write_measurements(d / "meas.h5", tx_gain_db=TX_GAIN_DB)
    return d


def _fit_and_score(d, device_gains: str, tag: str) -> tuple[dict, dict]:
    rf, res = d / f"rf_{tag}.h5", d / f"res_{tag}.json"
    r = CliRunner().invoke(app, ["--set", "rf_fit.physical.iterations=60",
                                 "--set", "rf_fit.physical.start_iterations=15",
                                 "--set", f"rf_fit.room.device_gains={device_gains}",
                                 "rf-fit", str(d / "scene.h5"), str(d / "meas.h5"), "-o", str(rf)])
    assert r.exit_code == 0, r.output
    r = CliRunner().invoke(app, ["predict", "rssi", str(rf), "--measurements", str(d / "meas.h5"),
                                 "-o", str(d / f"p_{tag}.h5"), "--results", str(res)])
    assert r.exit_code == 0, r.output
    return json.loads(res.read_text())["metrics"], read_artifact(rf, "rf").free.get("model", {})


def test_fitted_transmitter_gains_recover_the_offsets_and_lower_the_test_error(with_gains):
    off, _ = _fit_and_score(with_gains, "off", "off")
    on, model = _fit_and_score(with_gains, "tx", "tx")
    assert on["mae_db"] < off["mae_db"] - 0.5, (on["mae_db"], off["mae_db"])
    tx, _, _, _ = links()
    got, _ = gains_at(model, tx, np.full_like(tx, 99.0))
    # the gains' common part trades against the materials' level: compare offsets about their mean
    err = (got - got.mean()) - (TX_GAIN_DB - TX_GAIN_DB.mean())
    assert np.abs(err).max() < 1.0, (got, TX_GAIN_DB)


def test_bad_device_gains_setting_is_one_line(with_gains):
    r = CliRunner().invoke(app, ["--set", "rf_fit.room.device_gains=per-radio",
                                 "rf-fit", str(with_gains / "scene.h5"), str(with_gains / "meas.h5"),
                                 "-o", str(with_gains / "bad.h5")])
    assert r.exit_code != 0 and "device_gains" in r.output and "Traceback" not in r.output
    assert not (with_gains / "bad.h5").exists()


def test_auto_device_gains_are_off_for_ideal_simulated_devices_and_on_for_measured_data():
    """device_gains = "auto" (the default): off where the file records rfir's simulator and no measured-like
    transform (ideal devices), chosen by validation for measured-like and measured data (no simulator
    recorded); a value given is taken as given."""
    from types import SimpleNamespace

    from rfir_stages.rf_fit.room_stage import device_words, ideal_devices, room_config

    simulated = SimpleNamespace(free={"simulator@attrs": {"physics.max_depth": 3}})
    measured_like = SimpleNamespace(free={"simulator@attrs": {"physics.max_depth": 3, "measured_like": "gains"}})
    measured = SimpleNamespace(free={})
    assert [ideal_devices(m) for m in (simulated, measured_like, measured)] == [True, False, False]
    auto = {"room": {}}
    assert room_config(auto, 3, ideal=True)[0].device_gains == "off"
    assert room_config(auto, 3, ideal=False)[0].device_gains == "validate"
    assert room_config({"room": {"device_gains": "tx"}}, None, ideal=True)[0].device_gains == "tx"
    assert room_config({"room": {"device_gains": "off"}}, None, ideal=False)[0].device_gains == "off"
    assert "ideal devices" in device_words(auto, True) and "validation" in device_words(auto, False)
    assert device_words({"room": {"device_gains": "rx"}}, False) == "rf_fit.room.device_gains"


def test_measured_data_get_device_gains_by_default_and_say_so(with_gains):
    """A file that records no simulator (measured data) with transmitter offsets: every setting at its default
    chooses a gain per transmitter by validation on held-out receiver positions (per-position receiver gains
    carry to none of them), prints why, and stores the gains in the model."""
    d = with_gains
    write_measurements(d / "measured.h5", tx_gain_db=TX_GAIN_DB, simulated=False)
    r = CliRunner().invoke(app, ["--set", "rf_fit.physical.iterations=60", "--set", "rf_fit.physical.start_iterations=15",
                                 "rf-fit", str(d / "scene.h5"), str(d / "measured.h5"), "-o", str(d / "rf_auto.h5")])
    assert r.exit_code == 0, r.output
    assert "device gains: tx (auto: validated on" in r.output, r.output
    model = read_artifact(d / "rf_auto.h5", "rf").free.get("model", {})
    tx, _, _, _ = links()
    got, _ = gains_at(model, tx, np.full_like(tx, 99.0))
    err = (got - got.mean()) - (TX_GAIN_DB - TX_GAIN_DB.mean())
    assert np.abs(err).max() < 1.0, (got, TX_GAIN_DB)
