"""RSSI fits on geometry without object labels (what `rfir geom` writes from photos): the room model
fits a material per segment of the geometry."""
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact
from rfir_cli.main import app
from rfir_stages.geom import gaussians_from_mesh, write_scene_artifact

from .helpers import room_mesh, write_measurements


def _unlabelled_scene(path):
    v, f, _, _ = room_mesh()
    return write_scene_artifact(path, gaussians_from_mesh(v, f, 0.4), spacing_m=0.4)


def test_physical_room_model_on_unlabelled_geometry_uses_segments(tmp_path):
    _unlabelled_scene(tmp_path / "scene.h5")
    write_measurements(tmp_path / "meas.h5")
    r = CliRunner().invoke(app, ["--set", "rf_fit.physical.iterations=5",
                                 "--set", "rf_fit.physical.start_iterations=2", "rf-fit", str(tmp_path / "scene.h5"),
                                 str(tmp_path / "meas.h5"), "-o", str(tmp_path / "rf.h5")])
    assert r.exit_code == 0, r.output
    assert "materials per segment" in r.output
    assert read_artifact(tmp_path / "rf.h5", "rf").free["model@attrs"]["sharing"] == "segment"
