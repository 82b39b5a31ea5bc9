"""`rfir geom` at demo size: the lego's 60 photos (640 x 480), calibrated by SfM, trained at the default
settings; checks the held-out figures against the ground-truth mesh (docs/guide/photos-to-scene.md). Several minutes."""
import json

import pytest
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact
from rfir_cli.main import app

runner = CliRunner()


@pytest.mark.slow
def test_lego_demo_size_geometry(tmp_path):
    from rfir_stages.render import render_views
    from rfir_stages.simulate.scenes import build_scene, write_meshes

    spec = build_scene("lego")
    write_meshes(spec, tmp_path / "meshes")
    render_views(spec, tmp_path, write_depth=False)
    cameras = tmp_path / "cameras.h5"
    result = runner.invoke(app, ["calibrate", str(tmp_path / "images"), "-o", str(tmp_path / "calib.h5"),
                                 "--poses", str(cameras), "--intrinsics-from", str(cameras)])
    assert result.exit_code == 0, result.output
    result = runner.invoke(app, ["geom", str(tmp_path / "calib.h5"), "-o", str(tmp_path / "scene.h5")])
    assert result.exit_code == 0, result.output
    art = read_artifact(tmp_path / "scene.h5", "scene")
    m = json.loads(art.free["training@attrs"]["metrics_json"])
    assert m["psnr_db"] > 30.0
    assert m["normal_error_flat_deg_median"] < 8.0
    assert m["normal_error_deg_median"] < 15.0
    assert m["mesh_accuracy_m"] < 0.005
    assert m["depth_error_m_median"] < 0.005
