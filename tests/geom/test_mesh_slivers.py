"""`rfir mesh-gaussians` on sliver facets: merged (far fewer, wider surfels, area kept), counted, warned."""
import math

import numpy as np
import torch
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact
from rfir_cli.main import app
from rfir_core.physics.gaussian_rf import covariance, projected_cross_section_m2
from rfir_stages.geom import gaussians_from_mesh

from .test_mesh_gaussians import write_ply

runner = CliRunner()
SPACING = 0.03


def cylinder(radius=0.05, height=0.3, sides=32):
    """A closed prism of `sides` faces (side quads as two triangles, caps as fans): its side facets
    are 1 cm x 30 cm slivers at these sizes. Returns (vertices, faces, exact area m^2)."""
    a = np.arange(sides) * 2 * np.pi / sides
    ring = np.stack([radius * np.cos(a), radius * np.sin(a), np.zeros(sides)], 1)
    v = np.concatenate([ring, ring + [0, 0, height], [[0, 0, 0], [0, 0, height]]])
    f = []
    for i in range(sides):
        j = (i + 1) % sides
        f += [(i, j, sides + j), (i, sides + j, sides + i), (2 * sides, j, i), (2 * sides + 1, sides + i, sides + j)]
    edge = 2 * radius * math.sin(math.pi / sides)
    area = sides * edge * height + 2 * sides * 0.5 * radius**2 * math.sin(2 * math.pi / sides)
    return v, np.asarray(f), area


def _areas(fields) -> np.ndarray:
    cov = covariance(torch.tensor(fields["gaussians/log_scales"]), torch.tensor(fields["gaussians/rotations"]))
    return projected_cross_section_m2(cov.double(), torch.tensor(fields["gaussians/normals"])[None]).numpy()[0]


def _narrow(fields) -> int:
    return int((np.exp(fields["gaussians/log_scales"][:, :2]).min(1) < 0.05 * SPACING).sum())


def test_cylinder_slivers_are_merged_with_the_area_kept(monkeypatch):
    v, f, area = cylinder()
    report = {}
    merged = gaussians_from_mesh(v, f, SPACING, report=report)
    import rfir_stages.geom.from_mesh as from_mesh

    monkeypatch.setattr(from_mesh, "SLIVER_RATIO", 0.0)          # the tiling without the floor
    raw = gaussians_from_mesh(v, f, SPACING)
    assert len(raw["gaussians/means"]) == 8000 and _narrow(raw) > 7000        # thousands of 0.3 mm surfels
    assert len(merged["gaussians/means"]) < len(raw["gaussians/means"]) / 10
    assert _narrow(merged) < _narrow(raw) / 50
    assert math.isclose(_areas(merged).sum(), area, rel_tol=0.02)             # covered area kept
    assert math.isclose(_areas(raw).sum(), area, rel_tol=0.02)
    assert report["sliver_faces"] == 64 and report["sliver_surfels"] > 7000 and report["degenerate_faces"] == 0
    # merged surfels stay on the surface: every mean within the prism's radius and height
    m = merged["gaussians/means"]
    assert np.hypot(m[:, 0], m[:, 1]).max() <= 0.05 + 1e-9 and m[:, 2].min() >= -1e-9 and m[:, 2].max() <= 0.3 + 1e-9


def test_regular_faces_are_untouched_and_labels_follow_merged_surfels():
    v, f, _ = cylinder()
    labels = np.arange(len(f)) % 4 == 2                          # the bottom cap is label 1, the rest 0
    fields = gaussians_from_mesh(v, f, SPACING, labels=labels.astype(int))
    lab = fields["gaussians/labels"]
    assert len(lab) == len(fields["gaussians/means"])
    bottom = fields["gaussians/means"][lab == 1]
    assert np.abs(bottom[:, 2]).max() < 1e-9                      # label 1 surfels lie on the bottom cap only
    square = gaussians_from_mesh(np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0.0]]),
                                 np.array([[0, 1, 2], [0, 2, 3]]), 0.1, report=(rep := {}))
    assert rep["sliver_surfels"] == 0 and len(square["gaussians/means"]) == 2 * 15**2   # 1.41 m diagonal / 0.1 m
    assert math.isclose(_areas(square).sum(), 1.0, rel_tol=1e-6)


def test_cli_warns_with_counts_of_slivers_and_degenerate_facets(tmp_path):
    v, f, _ = cylinder()
    f = np.concatenate([f, [[0, 0, 1]]])                         # one zero-area facet
    mesh = write_ply(tmp_path / "cyl.ply", v, f)
    r = runner.invoke(app, ["mesh-gaussians", str(mesh), "-o", str(tmp_path / "s.h5"), "--spacing", str(SPACING)])
    assert r.exit_code == 0, r.output
    out = " ".join(r.output.split())
    assert "1 of 129 facets have zero area: skipped" in out
    assert "64 of 129 facets are slivers" in out and "area kept" in out
    assert len(read_artifact(tmp_path / "s.h5", "scene")["gaussians/means"]) < 800


def test_cli_refuses_a_mesh_without_area(tmp_path):
    mesh = write_ply(tmp_path / "flat.ply", [(0, 0, 0), (1, 0, 0), (2, 0, 0)], [(0, 1, 2)])
    r = runner.invoke(app, ["mesh-gaussians", str(mesh), "-o", str(tmp_path / "s.h5")])
    assert r.exit_code == 2 and "no face with a non-zero area" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "s.h5").exists()
