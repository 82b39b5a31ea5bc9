"""Rectangles of a mesh (two triangles sharing their diagonal) are tiled as cells whose footprints are the
rectangle to its edge; other triangles keep the sub-triangle tiling."""
import math

import numpy as np
import torch

from rfir_stages.geom import gaussians_from_mesh
from rfir_stages.model.surfels import footprint_cells, surfel_areas


def _rotation(axis, deg):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = math.radians(deg)
    return np.eye(3) + math.sin(a) * k + (1 - math.cos(a)) * k @ k


def _fields(vertices, faces, spacing):
    g = gaussians_from_mesh(vertices, faces, spacing, rectangles=True)
    t = {k.split("/")[1]: torch.as_tensor(v) for k, v in g.items()}
    areas = surfel_areas(t["means"], t["log_scales"], t["rotations"], t["normals"])
    cells = footprint_cells(t["log_scales"], t["rotations"], t["normals"], areas).numpy()
    return g, cells, areas.numpy()


def _covered(points, means, cells):
    """[N] bool: point inside one of the footprint rectangles (centres means, half-axes cells [G, 2, 3])."""
    rel = points[:, None, :] - means[None]                                         # [N, G, 3]
    half = np.linalg.norm(cells, axis=2)                                           # [G, 2]
    axes = cells / half[:, :, None]
    along = np.abs(np.einsum("ngi,gai->nga", rel, axes))
    return (along <= half[None] * (1 + 1e-5)).all(2).any(1)


def test_a_rectangle_is_tiled_by_cells_that_end_at_its_edges():
    """A 0.42 x 0.40 m rectangle, turned out of the axes, at 7 cm spacing: 12 x 12 cells of 3.5 x 3.33 cm along
    its sides, areas summing to the rectangle's; the cells' union covers points 1 mm inside every edge and no
    point 1 mm outside. Its two triangles tiled apart (not sharing the diagonal) overshoot the edge."""
    rot = _rotation([1, 2, 3], 37.0)
    a, b = 0.42, 0.40
    corners = np.array([[0, 0, 0], [a, 0, 0], [a, b, 0], [0, b, 0]], float) @ rot.T + [1.0, 2.0, 0.5]
    g, cells, areas = _fields(corners, np.array([[0, 1, 2], [0, 2, 3]]), 0.07)
    assert len(areas) == 12 * 12
    assert abs(areas.sum() - a * b) < 1e-5 * a * b          # surfel_areas: a tiling's coverage to 1e-5
    half = np.sort(np.linalg.norm(cells, axis=2), axis=1)
    np.testing.assert_allclose(half, np.tile([b / 24, a / 24], (len(half), 1)), rtol=1e-5)
    side = (corners[1] - corners[0]) / a
    assert np.allclose(np.abs(np.einsum("gai,i->ga", cells / half[:, ::-1][:, :, None], side)).max(1), 1.0)
    u = np.linspace(0.0, 1.0, 41)
    along_edges = []
    for i in range(4):
        p, q = corners[i], corners[(i + 1) % 4]
        inward = (corners[(i + 2) % 4] + corners[(i + 3) % 4]) / 2 - (p + q) / 2
        inward /= np.linalg.norm(inward)
        along_edges.append((p + u[:, None] * (q - p), inward))
    for pts, inward in along_edges:
        assert _covered(pts + 0.001 * inward, g["gaussians/means"], cells).all()
        assert not _covered(pts - 0.001 * inward, g["gaussians/means"], cells).any()
    apart = np.concatenate([corners, corners[[0, 2]]])                 # the same two triangles, diagonal not shared
    g2, cells2, _ = _fields(apart, np.array([[0, 1, 2], [4, 5, 3]]), 0.07)
    outside = np.concatenate([pts - 0.003 * inward for pts, inward in along_edges])
    assert _covered(outside, g2["gaussians/means"], cells2).any()


def test_square_cells_take_the_rectangle_sides_and_other_quads_stay_triangles():
    """Square cells (equal spreads) are laid along the rectangle's sides, turned 30 degrees about the normal;
    a parallelogram without a right angle is two triangles' sub-triangles (area kept, no cell of it square)."""
    rot = _rotation([0, 0, 1], 30.0)
    square = np.array([[0, 0, 0], [0.4, 0, 0], [0.4, 0.4, 0], [0, 0.4, 0]], float) @ rot.T
    g, cells, areas = _fields(square, np.array([[0, 1, 2], [0, 2, 3]]), 0.2)
    assert len(areas) == 16                                           # cells of at most spacing / 2
    first = cells[:, 0] / np.linalg.norm(cells[:, 0], axis=1, keepdims=True)
    np.testing.assert_allclose(np.maximum(np.abs(first @ rot[:, 0]), np.abs(first @ rot[:, 1])), 1.0, atol=1e-9)
    centres = g["gaussians/means"]
    edge = square[0] + np.linspace(0, 1, 21)[:, None] * (square[1] - square[0])
    inward = rot[:, 1]
    assert _covered(edge + 0.001 * inward, centres, cells).all()
    assert not _covered(edge - 0.001 * inward, centres, cells).any()
    para = np.array([[0, 0, 0], [0.4, 0, 0], [0.6, 0.4, 0], [0.2, 0.4, 0]], float)
    g, cells, areas = _fields(para, np.array([[0, 1, 2], [0, 2, 3]]), 0.2)
    assert abs(areas.sum() - 0.16) < 1e-5 * 0.16
    assert len(areas) % 2 == 0 and len(areas) > 4                     # m x m sub-triangles of each face


def test_the_command_tiles_rectangles_only_when_asked_and_records_the_tiling(tmp_path):
    """`rfir mesh-gaussians --rectangles`: the two panels' rectangles as cells (1 x 0.5 m at 0.2 m: 10 x 5, 0.4 x
    0.4 m: 4 x 4), the tiling in the artifact's provenance and the count printed; without it, sub-triangles."""
    from typer.testing import CliRunner

    from rfir_core.artifacts import read_artifact
    from rfir_cli.main import app

    from .test_mesh_gaussians import two_panels, write_ply

    mesh = write_ply(tmp_path / "m.ply", *two_panels())
    runner = CliRunner()
    r = runner.invoke(app, ["mesh-gaussians", str(mesh), "-o", str(tmp_path / "r.h5"), "--spacing", "0.2",
                            "--rectangles"])
    assert r.exit_code == 0, r.output
    assert "2 rectangles tiled as cells" in " ".join(r.output.split())
    art = read_artifact(tmp_path / "r.h5", "scene")
    assert len(art["gaussians/means"]) == 10 * 5 + 4 * 4
    assert art.provenance.extra["tiling"] == "rectangles"
    r = runner.invoke(app, ["mesh-gaussians", str(mesh), "-o", str(tmp_path / "t.h5"), "--spacing", "0.2"])
    assert r.exit_code == 0, r.output
    art = read_artifact(tmp_path / "t.h5", "scene")
    assert art.provenance.extra["tiling"] == "triangles" and len(art["gaussians/means"]) != 10 * 5 + 4 * 4
