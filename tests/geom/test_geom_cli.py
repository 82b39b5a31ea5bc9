"""`rfir geom` end to end on the synthetic plane: outputs, printed metrics, PLY layout, bad input."""
import numpy as np
import tomli_w
from plyfile import PlyData
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact, validate_artifact, write_artifact
from rfir_cli.main import app
from rfir_stages.geom.export_ply import NUM_REST, SH_C0, read_gaussian_ply, write_gaussian_ply

runner = CliRunner()


def _config_file(tmp_path, small_config, **over):
    path = tmp_path / "geom_test.toml"
    path.write_text(tomli_w.dumps({"geom": small_config(**over)}))
    return path


def test_cli_writes_scene_ply_mesh_renders_and_prints_metrics(plane_capture, small_config, tmp_path):
    calib, mesh = plane_capture
    cfg = _config_file(tmp_path, small_config, iterations=40)
    out = tmp_path / "out" / "scene.h5"
    result = runner.invoke(app, ["--config", str(cfg), "geom", str(calib), "-o", str(out), "--gt-mesh", str(mesh)])
    assert result.exit_code == 0, result.output
    assert "PSNR" in result.output and "normal error" in result.output and "Chamfer" in result.output
    assert validate_artifact(out, "scene") == []
    art = read_artifact(out, "scene")
    g = len(art["gaussians/means"])
    assert art["gaussians/colors"].shape == (g, 3)
    np.testing.assert_allclose(np.linalg.norm(art["gaussians/normals"], axis=1), 1.0, atol=1e-5)
    assert "psnr_db" in art.free["training@attrs"]["metrics_json"]
    assert art.provenance.stage == "geom" and str(calib) in art.provenance.inputs
    assert (tmp_path / "out" / "scene.ply").is_file()
    fused = PlyData.read(str(tmp_path / "out" / "scene_mesh.ply"))
    assert fused["face"].count > 10
    pngs = sorted(p.name for p in (tmp_path / "out" / "scene_renders").iterdir())
    assert {"view_001_color.png", "view_001_depth.png", "view_001_normal.png"} <= set(pngs)
    assert (tmp_path / "out" / "scene.h5.ckpt.pt").is_file()


def test_ply_round_trip_uses_the_splatting_layout(tmp_path):
    rng = np.random.default_rng(1)
    n = 7
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    normals = rng.normal(size=(n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    fields = {"gaussians/means": rng.normal(size=(n, 3)), "gaussians/log_scales": rng.normal(-4, 1, size=(n, 3)),
              "gaussians/rotations": q, "gaussians/opacities": rng.uniform(0.05, 0.95, n),
              "gaussians/colors": rng.uniform(0.05, 0.95, (n, 3)), "gaussians/normals": normals}
    path = write_gaussian_ply(tmp_path / "g.ply", fields)
    vertex = PlyData.read(str(path))["vertex"]
    names = list(vertex.data.dtype.names)
    want = (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"] + [f"f_rest_{i}" for i in range(NUM_REST)]
            + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])
    assert names == want
    assert all(vertex.data.dtype[name] == np.float32 for name in names)
    # stored as in splatting files: logit opacity, log scale, SH DC colour
    np.testing.assert_allclose(1 / (1 + np.exp(-vertex["opacity"])), fields["gaussians/opacities"], rtol=1e-5)
    np.testing.assert_allclose(0.5 + SH_C0 * vertex["f_dc_1"], fields["gaussians/colors"][:, 1], atol=1e-6)
    back = read_gaussian_ply(path)
    for key, value in fields.items():
        np.testing.assert_allclose(back[key], value, rtol=1e-5, atol=1e-6, err_msg=key)


def test_missing_calib_fails_with_one_line_and_writes_nothing(tmp_path):
    out = tmp_path / "scene.h5"
    result = runner.invoke(app, ["geom", str(tmp_path / "nope.h5"), "-o", str(out)])
    assert result.exit_code == 2
    assert "nope.h5" in result.output and "Traceback" not in result.output
    assert len(result.output.strip().splitlines()) == 1
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_wrong_kind_bad_config_and_missing_image_fail_clearly(plane_capture, tmp_path):
    calib, _ = plane_capture
    scene = tmp_path / "s.h5"
    write_artifact(scene, "scene", {"gaussians/means": np.zeros((1, 3)), "gaussians/log_scales": np.zeros((1, 3)),
                                    "gaussians/rotations": np.array([[1.0, 0, 0, 0]]), "gaussians/opacities": np.ones(1),
                                    "gaussians/normals": np.array([[0, 0, 1.0]])})
    result = runner.invoke(app, ["geom", str(scene), "-o", str(tmp_path / "o.h5")])
    assert result.exit_code == 3 and "kind 'scene'" in result.output
    result = runner.invoke(app, ["--set", "geom.iterations=0", "geom", str(calib), "-o", str(tmp_path / "o.h5")])
    assert result.exit_code == 4 and "geom.iterations" in result.output
    result = runner.invoke(app, ["--set", "geom.loss.normal=-1", "geom", str(calib), "-o", str(tmp_path / "o.h5")])
    assert result.exit_code == 4 and "geom.loss.normal" in result.output
    for bad, key in (("geom.test_every=1", "geom.test_every"), ("geom.init_opacity=1.5", "geom.init_opacity"),
                     ("geom.output.tsdf_voxel=0", "geom.output.tsdf_voxel")):
        result = runner.invoke(app, ["--set", bad, "geom", str(calib), "-o", str(tmp_path / "o.h5")])
        assert result.exit_code == 4 and key in result.output, bad
    # a calibration naming a photo that is gone
    art = read_artifact(calib, "calib")
    data = dict(art.data)
    data["image_paths"] = np.asarray(["images/missing.png"] + list(data["image_paths"][1:]), dtype=object)
    broken = calib.parent / "broken_calib.h5"
    write_artifact(broken, "calib", data, attrs={"metric": True})
    result = runner.invoke(app, ["geom", str(broken), "-o", str(tmp_path / "o.h5")])
    assert result.exit_code == 2 and "missing.png" in result.output and "Traceback" not in result.output
    # a calibration whose image size does not match the photos
    data = dict(art.data)
    data["image_size"] = data["image_size"] * 2
    write_artifact(broken, "calib", data, attrs={"metric": True})
    result = runner.invoke(app, ["geom", str(broken), "-o", str(tmp_path / "o.h5")])
    assert result.exit_code == 2 and "the calibration says 128 x 96" in result.output
    assert not (tmp_path / "o.h5").exists()


def test_resume_after_finish_and_empty_mesh_warning(plane_capture, small_config, tmp_path):
    calib, _ = plane_capture
    cfg = _config_file(tmp_path, small_config, iterations=20, checkpoint_every=10, output={"tsdf_voxel": 0.0005})
    out = tmp_path / "scene.h5"
    args = ["--config", str(cfg), "geom", str(calib), "-o", str(out)]
    first = runner.invoke(app, args)
    assert first.exit_code == 0, first.output
    assert "fused mesh is empty" in first.output and not (tmp_path / "scene_mesh.ply").exists()
    before = read_artifact(out, "scene")
    again = runner.invoke(app, args + ["--resume"])
    assert again.exit_code == 0, again.output
    assert "resumed from the checkpoint at step 20" in again.output
    after = read_artifact(out, "scene")
    # the checkpoint holds the finished run (the stored normals are oriented after training, again)
    np.testing.assert_array_equal(before["gaussians/means"], after["gaussians/means"])
    np.testing.assert_allclose(before["gaussians/normals"], after["gaussians/normals"])
