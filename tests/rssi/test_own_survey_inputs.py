"""rf-fit on a user's own RSSI survey: links from a point to itself, positions in another unit, no split column."""
import numpy as np
import pytest
from typer.testing import CliRunner

from rfir_core.artifacts import write_artifact
from rfir_cli.main import app

from .helpers import links, reference_gain_db, write_scene

FAST = ["--set", "rf_fit.physical.iterations=20", "--set", "rf_fit.physical.start_iterations=5",
        "--set", "rf_fit.room.tabulated_materials=false", "--set", "rf_fit.room.device_gains=off"]


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    d = tmp_path_factory.mktemp("own")
    write_scene(d / "scene.h5", spacing_m=0.6)
    return d


def _measurements(path, scale=1.0, same_point=0, split=True):
    tx, rx, ti, ri = links()
    t, r = tx[ti].copy(), rx[ri].copy()
    r[:same_point] = t[:same_point]            # a link from a transmitter to itself
    gain = reference_gain_db(t, r + 1e-9, 2.4e9)
    gain[:same_point] = -30.0
    data = {"tx_pos": t * scale, "rx_pos": r * scale, "freq_hz": np.array([2.4e9]), "path_gain_db": gain[:, None]}
    if split:
        data["split"] = (np.arange(len(t)) % 5 == 4).astype(np.int64)
    write_artifact(path, "measurements", data, attrs={"task": "rssi", "scene": "own"})
    return path


def _fit(room, meas, out):
    return CliRunner().invoke(app, FAST + ["rf-fit", str(room / "scene.h5"), str(meas), "-o", str(out)])


def test_links_from_a_point_to_itself_are_left_out_and_counted(room):
    r = _fit(room, _measurements(room / "same.h5", same_point=2), room / "rf_same.h5")
    assert r.exit_code == 0, r.output
    assert "2 of " in r.output and "transmitter at the receiver" in r.output and "left out" in r.output


def test_positions_in_centimetres_are_refused_naming_the_flag(room):
    out = room / "rf_cm.h5"
    r = _fit(room, _measurements(room / "cm.h5", scale=100.0), out)
    assert r.exit_code == 2, r.output
    line = r.output.strip().splitlines()[-1]
    assert "outside the geometry's extent" in line and "--position-unit cm" in line and "Traceback" not in r.output
    assert not out.exists()


def test_a_file_without_a_split_column_trains_on_every_link_and_says_so(room):
    r = _fit(room, _measurements(room / "nosplit.h5", split=False), room / "rf_nosplit.h5")
    assert r.exit_code == 0, r.output
    assert "no split column: every link trains the model" in r.output
    assert "120 training links" in r.output


def test_link_weights_are_the_inverse_error_variance_about_a_mean_of_one():
    from rfir_stages.model.fit_physical import MODEL_ERROR_DB, link_weights

    assert link_weights(None, None) is None
    w = link_weights(np.array([1, 16, 1]), np.array([[4.0], [4.0], [0.0]]))[:, 0]
    want = 1 / (MODEL_ERROR_DB ** 2 + np.array([16.0, 1.0, 0.0]))
    np.testing.assert_allclose(w, want / want.mean())
    assert w.mean() == pytest.approx(1.0) and w[0] < w[1] < w[2]


def test_averaged_links_weight_the_fit_toward_the_well_measured_ones(room):
    """Half the links are single noisy samples 6 dB off (n 1, spread 8 dB), half the mean of 30 samples (spread
    1 dB): weighted by their counts and spreads, the fit follows the well-measured half."""
    from rfir_core.artifacts import read_artifact
    from rfir_stages.model.room import RoomPredictor

    tx, rx, ti, ri = links()
    t, r = tx[ti], rx[ri]
    gain = reference_gain_db(t, r, 2.4e9)
    noisy = np.arange(len(t)) % 2 == 1
    measured = gain + np.where(noisy, 6.0, 0.0)
    base = {"tx_pos": t, "rx_pos": r, "freq_hz": np.array([2.4e9]), "path_gain_db": measured[:, None],
            "split": np.zeros(len(t), np.int64)}
    write_artifact(room / "plain.h5", "measurements", base, attrs={"task": "rssi", "scene": "own"})
    write_artifact(room / "avg.h5", "measurements",
                   {**base, "sample_count": np.where(noisy, 1, 30).astype(np.int64),
                    "sample_std_db": np.where(noisy, 8.0, 1.0)[:, None]}, attrs={"task": "rssi", "scene": "own"})
    errors = {}
    for name in ("plain", "avg"):
        out = room / f"rf_{name}.h5"
        res = _fit(room, room / f"{name}.h5", out)
        assert res.exit_code == 0, res.output
        assert ("links weighted by their sample count" in res.output) == (name == "avg")
        model = read_artifact(out, "rf")
        pred = RoomPredictor(model).path_gain_db(t, r)
        errors[name] = float(np.abs(pred - gain)[~noisy].mean())
    assert errors["avg"] < errors["plain"] - 0.5, errors
