"""A fitted room model of the reduced RSSI test room (tests/rssi/helpers.py), shared by the predict rssi tests."""
import pytest
from typer.testing import CliRunner

from rfir_cli.main import app

from ..rssi.helpers import write_measurements, write_scene

# a short fit: the tests are about the maps' plumbing, not the model's accuracy
FAST = ["--set", "rf_fit.physical.iterations=20", "--set", "rf_fit.physical.start_iterations=5"]


@pytest.fixture(scope="session")
def rssi_rf(tmp_path_factory):
    """Path of the rf artifact fitted on the reduced room's synthetic RSSI measurements."""
    d = tmp_path_factory.mktemp("rssi_rf")
    write_scene(d / "scene.h5")
    write_measurements(d / "meas.h5")
    r = CliRunner().invoke(app, [*FAST, "rf-fit", str(d / "scene.h5"), str(d / "meas.h5"), "-o", str(d / "rf.h5")])
    assert r.exit_code == 0, r.output
    return d / "rf.h5"
