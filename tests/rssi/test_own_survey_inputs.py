"""rf-fit on a user's own RSSI survey: links from a point to itself, positions in another unit, no split column."""
import numpy as np
import pytest
from typer.testing import CliRunner

from rfir_cli.artifacts import write_artifact
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
