"""`rfir import floorplan`: a two-room plan -> closed, labelled wall boxes, a floor and a ceiling, named so that
rf-fit's classes and starting materials follow; mesh-gaussians --preset room reads it; bad plans fail in one line, nothing
written."""
import json

import numpy as np
import pytest
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact
from rfir_cli.main import app
from rfir_stages.geom.mesh_io import read_ply_mesh

runner = CliRunner()

# two rooms of 3 x 4 m: a concrete shell (centre lines on x 0..6, y 0..4), a plasterboard partition at x = 3, and a
# glass pane 0.9-2.2 m high standing in the east room (a partial-height row)
TWO_ROOMS = """# two rooms
x0,y0,x1,y1,thickness_m,material,height_m,z0_m
0,0,6,0,0.2,concrete,,
6,0,6,4,0.2,concrete,,
6,4,0,4,0.2,Concrete,,
0,4,0,0,0.2,concrete,,

3,0,3,4,0.1,plasterboard,,
4,2,5,2,0.006,glass,1.3,0.9
"""
HEIGHT = 2.7
LENGTHS = [6, 4, 6, 4, 4, 1]
THICK = [0.2, 0.2, 0.2, 0.2, 0.1, 0.006]
TALL = [2.7] * 5 + [1.3]


def run_import(tmp_path, text=TWO_ROOMS, *flags):
    plan = tmp_path / "walls.csv"
    plan.write_text(text)
    if "--walls" not in flags:      # the box tests; sheet (the default) is asked for by name where tested
        flags = ("--walls", "box", *flags)
    return runner.invoke(app, ["import", "floorplan", str(plan), "-o", str(tmp_path / "room.ply"), "--height",
                               str(HEIGHT), *flags])


def closed_and_outward(vertices, faces):
    """(every edge shared by exactly two faces, by position; enclosed volume [m^3], positive when the faces wind
    counter-clockwise seen from outside)."""
    keyed = np.round(vertices, 6)
    edges = {}
    for f in faces:
        for a, b in ((f[0], f[1]), (f[1], f[2]), (f[2], f[0])):
            key = tuple(sorted((tuple(keyed[a]), tuple(keyed[b]))))
            edges[key] = edges.get(key, 0) + 1
    tri = vertices[faces]
    volume = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6
    return all(n == 2 for n in edges.values()), volume


def test_two_rooms_give_closed_labelled_boxes(tmp_path):
    result = run_import(tmp_path)
    assert result.exit_code == 0, result.output
    output = " ".join(result.output.split())
    assert "6 walls (concrete 4, plasterboard 1, glass 1)" in output and "--preset room" in output
    mesh = read_ply_mesh(tmp_path / "room.ply")
    assert len(mesh.faces) == 12 * 8                                   # six walls, a floor and a ceiling
    names = [mesh.label_names[i] for i in range(8)]
    assert names == ["concrete_00", "concrete_01", "concrete_02", "concrete_03", "plasterboard_00", "glass_00",
                     "floor", "ceiling"]
    for label in range(6):
        faces = mesh.faces[mesh.labels == label]
        closed, volume = closed_and_outward(mesh.vertices, faces)
        assert len(faces) == 12 and closed
        assert volume == pytest.approx(LENGTHS[label] * THICK[label] * TALL[label], rel=1e-5)
        corners = mesh.vertices[np.unique(faces)]
        size = corners.max(0) - corners.min(0)
        along = max(size[0], size[1])
        assert along == pytest.approx(LENGTHS[label], abs=1e-5)
        assert min(size[0], size[1]) == pytest.approx(THICK[label], abs=1e-6)
        assert size[2] == pytest.approx(TALL[label], abs=1e-6)
    pane = mesh.vertices[np.unique(mesh.faces[mesh.labels == 5])]
    assert pane[:, 2].min() == pytest.approx(0.9, abs=1e-6) and pane[:, 2].max() == pytest.approx(2.2, abs=1e-6)
    floor, ceiling = (mesh.vertices[np.unique(mesh.faces[mesh.labels == k])] for k in (6, 7))
    np.testing.assert_allclose(floor.min(0), [-0.1, -0.1, -0.2], atol=1e-6)     # the walls' outline, 0.2 m slab
    np.testing.assert_allclose(floor.max(0), [6.1, 4.1, 0.0], atol=1e-6)
    np.testing.assert_allclose(ceiling[:, 2].min(), HEIGHT, atol=1e-6)
    for label in (6, 7):
        closed, volume = closed_and_outward(mesh.vertices, mesh.faces[mesh.labels == label])
        assert closed and volume == pytest.approx(6.2 * 4.2 * 0.2, rel=1e-5)
    labels = json.loads((tmp_path / "labels.json").read_text())
    assert [o["radio_material"] for o in labels["objects"]] == ["concrete"] * 4 + ["plasterboard", "glass", None,
                                                                                   None]
    assert [o["thickness_m"] for o in labels["objects"]][:6] == THICK


def test_classes_and_starting_materials_follow_the_names(tmp_path):
    """rf-fit's classes (the name without _NN) are the materials, and each names its ITU material."""
    from rfir_stages.model.fit_physical import label_class_names
    from rfir_stages.model.tabulated import named_material

    assert run_import(tmp_path, TWO_ROOMS, "--floor-material", "Concrete").exit_code == 0
    names = [read_ply_mesh(tmp_path / "room.ply").label_names[i] for i in range(8)]
    classes = label_class_names(names)
    assert sorted(set(classes)) == ["ceiling", "concrete", "floor_concrete", "glass", "plasterboard"]
    assert [named_material(c) for c in ("concrete", "floor_concrete", "glass", "plasterboard", "ceiling")] == [
        "concrete", "concrete", "glass", "plasterboard", None]


def test_mesh_gaussians_room_preset_runs_on_the_plan(tmp_path):
    assert run_import(tmp_path).exit_code == 0
    result = runner.invoke(app, ["mesh-gaussians", str(tmp_path / "room.ply"), "-o", str(tmp_path / "s.h5"),
                                 "--preset", "room"])
    output = " ".join(result.output.split())
    assert result.exit_code == 0, result.output
    assert "at 80 cm spacing" in output and "(preset room)" in output and "rectangles tiled as cells" in output
    assert "left out" in output       # the walls' bottoms on the floor, their tops under the ceiling
    art = read_artifact(tmp_path / "s.h5", "scene")
    assert [str(n) for n in art.attrs["label_names"]][-2:] == ["floor", "ceiling"]
    assert set(np.unique(art["gaussians/labels"])) == set(range(8))


def test_sheet_walls(tmp_path):
    result = run_import(tmp_path, TWO_ROOMS, "--walls", "sheet")
    assert result.exit_code == 0, result.output
    mesh = read_ply_mesh(tmp_path / "room.ply")
    assert len(mesh.faces) == 2 * 8
    wall = mesh.vertices[np.unique(mesh.faces[mesh.labels == 4])]                 # the partition on x = 3
    np.testing.assert_allclose(wall[:, 0], 3.0, atol=1e-6)
    tri = mesh.vertices[mesh.faces[mesh.labels == 6]]
    assert np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])[:, 2].min() > 0   # the floor faces up
    tri = mesh.vertices[mesh.faces[mesh.labels == 7]]
    assert np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])[:, 2].max() < 0   # the ceiling down


def test_sheet_walls_are_the_default(tmp_path):
    """The room model reads each surface as one slab: a wall is one sheet unless a box is asked for."""
    plan = tmp_path / "walls.csv"
    plan.write_text(TWO_ROOMS)
    result = runner.invoke(app, ["import", "floorplan", str(plan), "-o", str(tmp_path / "room.ply"),
                                 "--height", str(HEIGHT)])
    assert result.exit_code == 0, result.output
    assert len(read_ply_mesh(tmp_path / "room.ply").faces) == 2 * 8


HEAD = "x0,y0,x1,y1,thickness_m,material\n"


@pytest.mark.parametrize("text, message", [
    (HEAD + "0,0,0,0,0.2,concrete\n", "line 2: zero-length wall (0, 0) -> (0, 0)"),
    (HEAD + "0,0,4,0,0,concrete\n", "line 2: thickness_m must be positive, got 0"),
    (HEAD + "0,0,4,0,-0.1,concrete\n", "line 2: thickness_m must be positive, got -0.1"),
    (HEAD.strip() + ",height_m\n0,0,4,0,0.2,concrete,0\n", "line 2: height_m must be positive, got 0"),
    (HEAD.strip() + ",height_m\n0,0,4,0,0.2,concrete,-2\n", "line 2: height_m must be positive, got -2"),
    (HEAD + "0,0,4,nan,0.2,concrete\n", "line 2: y1 is nan (a finite number is needed)"),
    (HEAD + "0,0,4,0,thick,concrete\n", "line 2: thickness_m 'thick' is not a number"),
    (HEAD + "0,0,4,0,0.2,\n", "line 2: material '' is empty"),
    (HEAD + "0,0,4,0,0.2\n", "line 2: 5 fields, the header has 6"),
    ("x0,y0,x1,y1,material\n0,0,4,0,concrete\n", "line 1: missing column thickness_m"),
    ("x0,y0,x1,y1,thickness,material\n0,0,4,0,0.2,concrete\n", "line 1: missing column thickness_m"),
    (HEAD.strip() + ",height\n0,0,4,0,0.2,concrete,2\n", "line 1: unknown column 'height'"),
    (HEAD.strip() + ",z0_m\n0,0,4,0,0.2,concrete,2\n", "line 2: the wall reaches 4.7 m, above the ceiling at 2.7 m"),
    ("# nothing\n", "no header row"),
    (HEAD, "line 1: a header but no walls"),
    (HEAD + "0,0,4,0,0.2,concrete\n\n# a comment\n4,0,4,0,0.2,concrete\n", "line 5: zero-length wall"),
])
def test_bad_plans_one_line_nothing_written(tmp_path, text, message):
    result = run_import(tmp_path, text)
    output = " ".join(result.output.split())
    assert result.exit_code == 2, result.output
    assert f"walls.csv: {message}" in output
    assert "Traceback" not in result.output and len(result.output.strip().splitlines()) <= 2
    assert not (tmp_path / "room.ply").exists() and not (tmp_path / "labels.json").exists()


def test_bad_options_and_other_meshes_labels_kept(tmp_path):
    result = run_import(tmp_path, TWO_ROOMS, "--slab", "0")
    assert result.exit_code == 4 and "--slab must be positive" in result.output
    result = run_import(tmp_path, TWO_ROOMS, "--walls", "curtain")
    assert result.exit_code == 4 and "--walls must be one of box, sheet" in result.output
    assert not (tmp_path / "room.ply").exists()
    # a labels.json of another mesh in the folder is not replaced; a rerun replaces its own output
    other = tmp_path / "labels.json"
    other.write_text(json.dumps({"scene": "classroom", "objects": [{"label": 0, "name": "desk_00"}]}))
    result = run_import(tmp_path)
    assert result.exit_code == 2 and "labels.json: exists (labels of 'classroom')" in " ".join(result.output.split())
    assert "desk_00" in other.read_text() and not (tmp_path / "room.ply").exists()
    other.unlink()
    assert run_import(tmp_path).exit_code == 0
    assert run_import(tmp_path, TWO_ROOMS, "--walls", "sheet").exit_code == 0
    assert len(read_ply_mesh(tmp_path / "room.ply").faces) == 16
