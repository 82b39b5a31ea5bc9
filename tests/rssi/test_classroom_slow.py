"""The whole chain on simulate's quick classroom (Sionna RT, 2 Tx x 20 Rx): slow, run with -m slow."""
import json

import pytest
from typer.testing import CliRunner

from rfir_cli.main import app

pytest.importorskip("sionna.rt")


@pytest.mark.slow
def test_quick_classroom_chain(tmp_path):
    run = lambda *a: CliRunner().invoke(app, [str(x) for x in a])  # noqa: E731
    r = run("simulate", "classroom", tmp_path / "sim", "--quick", "--no-photos")
    assert r.exit_code == 0, r.output
    r = run("mesh-gaussians", tmp_path / "sim/meshes/classroom_gt.ply", "-o", tmp_path / "scene.h5", "--spacing", "0.8")
    assert r.exit_code == 0, r.output
    r = run("rf-fit", tmp_path / "scene.h5", tmp_path / "sim/measurements.h5", "-o", tmp_path / "rf.h5")
    assert r.exit_code == 0, r.output
    res = tmp_path / "res.json"
    r = run("predict", "rssi", tmp_path / "rf.h5", "--measurements", tmp_path / "sim/measurements.h5",
            "-o", tmp_path / "p.h5", "--results", res, "--plots", tmp_path / "plots")
    assert r.exit_code == 0, r.output
    m = json.loads(res.read_text())["metrics"]
    assert m["num_test"] > 0 and m["mae_db"] < 10.0   # a sanity bound: 40 links are too few for the classroom's figure
