"""`rfir mesh-gaussians`: surfels cover the mesh area, follow face normals and labels; bad meshes fail clearly."""
import math

import numpy as np
import pytest
from plyfile import PlyData, PlyElement
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact
from rfir_cli.main import app
from rfir_core.physics.gaussian_rf import covariance, projected_cross_section_m2

runner = CliRunner()


def write_ply(path, vertices, faces, labels=None):
    vert = np.array([tuple(v) for v in vertices], dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    dtype = [("vertex_indices", "i4", (len(faces[0]),))] + ([("label", "i4")] if labels is not None else [])
    rows = [(list(f),) + ((int(labels[i]),) if labels is not None else ()) for i, f in enumerate(faces)]
    face = np.array(rows, dtype=dtype)
    PlyData([PlyElement.describe(vert, "vertex"), PlyElement.describe(face, "face")]).write(str(path))
    return path


def two_panels():
    """A 1 x 0.5 m panel facing +z (label 0) and a 0.4 x 0.4 m panel facing +x (label 1)."""
    v = [(0, 0, 0), (1, 0, 0), (1, 0.5, 0), (0, 0.5, 0), (2, 0, 0), (2, 0.4, 0), (2, 0.4, 0.4), (2, 0, 0.4)]
    f = [(0, 1, 2), (0, 2, 3), (4, 5, 6), (4, 6, 7)]
    return v, f, [0, 0, 1, 1]


def test_surfels_cover_area_follow_normals_and_labels(tmp_path):
    v, f, labels = two_panels()
    mesh = write_ply(tmp_path / "m.ply", v, f, labels)
    result = runner.invoke(app, ["mesh-gaussians", str(mesh), "-o", str(tmp_path / "s.h5"), "--spacing", "0.05"])
    assert result.exit_code == 0, result.output
    art = read_artifact(tmp_path / "s.h5", "scene")
    import torch

    normals = art["gaussians/normals"]
    lab = art["gaussians/labels"]
    np.testing.assert_allclose(normals[lab == 0], np.tile([0, 0, 1], ((lab == 0).sum(), 1)), atol=1e-9)
    np.testing.assert_allclose(normals[lab == 1], np.tile([1, 0, 0], ((lab == 1).sum(), 1)), atol=1e-9)
    cov = covariance(torch.tensor(art["gaussians/log_scales"]), torch.tensor(art["gaussians/rotations"]))
    area = projected_cross_section_m2(cov.double(), torch.tensor(normals)[None]).numpy()[0]
    assert math.isclose(area[lab == 0].sum(), 0.5, rel_tol=1e-3)
    assert math.isclose(area[lab == 1].sum(), 0.16, rel_tol=1e-3)
    assert np.all(np.exp(art["gaussians/log_scales"]).max(axis=1) <= 0.05)


@pytest.mark.parametrize("content, message", [
    (None, "file not found"),
    (b"hello, not a mesh", "not a readable PLY file"),
])
def test_bad_files(tmp_path, content, message):
    path = tmp_path / "bad.ply"
    if content is not None:
        path.write_bytes(content)
    result = runner.invoke(app, ["mesh-gaussians", str(path), "-o", str(tmp_path / "s.h5")])
    assert result.exit_code == 2 and message in result.output and "Traceback" not in result.output
    assert not (tmp_path / "s.h5").exists()


def test_quads_and_bad_spacing_are_refused(tmp_path):
    quad = write_ply(tmp_path / "q.ply", [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [(0, 1, 2, 3)])
    result = runner.invoke(app, ["mesh-gaussians", str(quad), "-o", str(tmp_path / "s.h5")])
    assert result.exit_code == 2 and "only triangle meshes" in result.output
    v, f, _ = two_panels()
    mesh = write_ply(tmp_path / "m.ply", v, f)
    result = runner.invoke(app, ["mesh-gaussians", str(mesh), "-o", str(tmp_path / "s.h5"), "--spacing", "0"])
    assert result.exit_code == 4 and "--spacing must be positive" in result.output


def test_object_cells_tile_each_object_at_its_size_over_n(tmp_path):
    """--object-cells N: each labelled object at min(--spacing, its size / N); area and labels kept."""
    v, f, labels = two_panels()   # sizes 1.0 m (label 0) and 0.4 m (label 1)
    mesh = write_ply(tmp_path / "m.ply", v, f, labels)
    result = runner.invoke(app, ["mesh-gaussians", str(mesh), "-o", str(tmp_path / "s.h5"), "--spacing", "0.3",
                                 "--object-cells", "8"])
    assert result.exit_code == 0, result.output
    assert "2 smaller objects at 5-12.5 cm (size / 8)" in " ".join(result.output.split())
    art = read_artifact(tmp_path / "s.h5", "scene")
    import torch

    lab = art["gaussians/labels"]
    sizes = np.exp(art["gaussians/log_scales"]).max(axis=1)
    cov = covariance(torch.tensor(art["gaussians/log_scales"]), torch.tensor(art["gaussians/rotations"]))
    area = projected_cross_section_m2(cov.double(), torch.tensor(art["gaussians/normals"])[None]).numpy()[0]
    for value, size_m, area_m2 in ((0, 1.0, 0.5), (1, 0.4, 0.16)):
        # a sub-triangle's longest edge is at most size / 8, its largest standard deviation below that
        assert sizes[lab == value].max() <= size_m / 8
        assert math.isclose(area[lab == value].sum(), area_m2, rel_tol=1e-3)
    # without the option both panels are tiled at 0.3 m: far fewer surfels
    result = runner.invoke(app, ["mesh-gaussians", str(mesh), "-o", str(tmp_path / "u.h5"), "--spacing", "0.3"])
    assert result.exit_code == 0 and len(read_artifact(tmp_path / "u.h5", "scene")["gaussians/means"]) < len(lab) / 4


def test_object_cells_need_labels(tmp_path):
    v, f, _ = two_panels()
    mesh = write_ply(tmp_path / "m.ply", v, f)
    result = runner.invoke(app, ["mesh-gaussians", str(mesh), "-o", str(tmp_path / "s.h5"), "--object-cells", "8"])
    assert result.exit_code == 2 and "needs a per-face 'label'" in result.output and "Traceback" not in result.output
    assert not (tmp_path / "s.h5").exists()
