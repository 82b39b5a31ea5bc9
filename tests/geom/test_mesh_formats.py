"""`rfir mesh-gaussians` on OBJ, STL and glTF/GLB: the same small room read from each format, with the labels the
format names (OBJ groups, glTF nodes); an unknown extension refused in one line; the --preset values and the
warning for a room tiled at the object spacing."""
import base64
import json
import struct

import numpy as np
import pytest
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact
from rfir_cli.main import app

runner = CliRunner()

ROOM = ((0.0, 0.0, 0.0), (3.0, 2.0, 2.5))       # a 3 x 2 x 2.5 m box
DESK = ((1.0, 0.5, 0.0), (2.2, 1.1, 0.75))       # a desk-sized block standing on the floor
QUADS = ((0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (2, 3, 7, 6), (1, 2, 6, 5), (0, 4, 7, 3))   # outward
INWARD = tuple(q[::-1] for q in QUADS)            # the room's faces face into it


def corners(lo, hi):
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    return [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0),
            (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)]


def triangles(lo, hi, quads=QUADS):
    v = np.array(corners(lo, hi))
    return np.array([[v[q[0]], v[q[k]], v[q[k + 1]]] for q in quads for k in (1, 2)])


def write_obj(path, groups=True):
    """Two boxes as quads, the second with negative (relative) indices and v/vt/vn corners."""
    lines = ["# a room and a desk", "mtllib none.mtl"]
    for i, (name, box) in enumerate((("room_shell", ROOM), ("desk_00", DESK))):
        if groups:
            lines.append(f"{'o' if i == 0 else 'g'} {name}")
        lines += [f"v {x} {y} {z}" for x, y, z in corners(*box)]
        if i == 0:
            lines += ["f " + " ".join(str(c + 1) for c in q) for q in INWARD]
        else:
            lines += ["f " + " ".join(f"{c - 8}/1/1" for c in q) for q in QUADS]
    path.write_text("\n".join(lines) + "\n")
    return path


def write_ascii_stl(path):
    rows = ["solid room"]
    for tri in np.concatenate([triangles(*ROOM, INWARD), triangles(*DESK)]):
        rows += ["facet normal 0 0 0", "outer loop", *[f"vertex {x} {y} {z}" for x, y, z in tri], "endloop",
                 "endfacet"]
    path.write_text("\n".join(rows + ["endsolid room"]) + "\n")
    return path


def write_binary_stl(path):
    tri = np.concatenate([triangles(*ROOM, INWARD), triangles(*DESK)]).astype("<f4")
    body = b"".join(struct.pack("<3f", 0, 0, 0) + t.tobytes() + b"\0\0" for t in tri)
    path.write_bytes(b"binary stl".ljust(80, b" ") + struct.pack("<I", len(tri)) + body)
    return path


def gltf_document(y_up=True):
    """Two nodes (room_shell; desk_00 as a child with a translation) sharing nothing, in one base64 buffer."""
    def to_file(p):     # rfir (x, y, z) -> glTF y up (x, z, -y)
        p = np.asarray(p, dtype=np.float32)
        return np.stack([p[:, 0], p[:, 2], -p[:, 1]], 1) if y_up else p

    room = to_file(corners(*ROOM))
    desk = to_file(np.array(corners(*DESK)) - np.array(DESK[0]))      # placed by the node's translation
    idx = np.array([[[q[0], q[k], q[k + 1]] for q in quads for k in (1, 2)] for quads in (INWARD, QUADS)],
                   dtype="<u2").reshape(-1)
    blob = room.tobytes() + desk.tobytes() + idx.tobytes()
    n = len(room) * 12
    shift = to_file([DESK[0]])[0].tolist()
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"name": "room_shell", "mesh": 0, "children": [1]}, {"name": "desk_00", "mesh": 1,
                                                                        "translation": shift}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 2}]},
                   {"primitives": [{"attributes": {"POSITION": 1}, "indices": 3}]}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 8, "type": "VEC3"},
                      {"bufferView": 0, "byteOffset": n, "componentType": 5126, "count": 8, "type": "VEC3"},
                      {"bufferView": 1, "componentType": 5123, "count": 36, "type": "SCALAR"},
                      {"bufferView": 1, "byteOffset": 72, "componentType": 5123, "count": 36, "type": "SCALAR"}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 2 * n},
                        {"buffer": 0, "byteOffset": 2 * n, "byteLength": idx.nbytes}],
        "buffers": [{"byteLength": len(blob)}],
    }
    return doc, blob


def write_gltf(path):
    doc, blob = gltf_document()
    doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
    path.write_text(json.dumps(doc))
    return path


def write_glb(path):
    doc, blob = gltf_document()
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    blob += b"\0" * (-len(blob) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + blob
    path.write_bytes(struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks)
    return path


def read_back(path, *flags):
    out = path.with_suffix(".h5")
    result = runner.invoke(app, ["mesh-gaussians", str(path), "-o", str(out), "--spacing", "0.5", *flags])
    assert result.exit_code == 0, result.output
    return read_artifact(out, "scene"), " ".join(result.output.split())


def area_of(art):
    """Total surfel area [m^2]: the two largest standard deviations, as mesh-gaussians sizes them."""
    import torch

    from rfir_core.physics.gaussian_rf import covariance, projected_cross_section_m2

    cov = covariance(torch.tensor(art["gaussians/log_scales"]), torch.tensor(art["gaussians/rotations"]))
    return float(projected_cross_section_m2(cov.double(), torch.tensor(art["gaussians/normals"])[None]).sum())


ROOM_AREA = 2 * (3 * 2 + 3 * 2.5 + 2 * 2.5)
DESK_AREA = 2 * (1.2 * 0.6 + 1.2 * 0.75 + 0.6 * 0.75)


@pytest.mark.parametrize("writer, suffix, labelled", [
    (write_obj, ".obj", True), (write_ascii_stl, ".stl", False), (write_binary_stl, ".stl", False),
    (write_gltf, ".gltf", True), (write_glb, ".glb", True)])
def test_each_format_gives_the_room(tmp_path, writer, suffix, labelled):
    path = writer(tmp_path / f"room{suffix}")
    art, output = read_back(path)
    means = art["gaussians/means"]
    np.testing.assert_allclose(means.min(0), ROOM[0], atol=0.26)       # z up, in metres, where it was written
    np.testing.assert_allclose(means.max(0), ROOM[1], atol=0.26)
    assert abs(area_of(art) - (ROOM_AREA + DESK_AREA)) < 1e-3 * ROOM_AREA
    if labelled:
        names = [str(n) for n in art.attrs["label_names"]]
        assert names == ["room_shell", "desk_00"]
        lab = art["gaussians/labels"]
        desk = means[lab == 1]
        assert desk.min(0)[2] >= -1e-6 and desk.max(0)[2] <= 0.75 + 1e-6 and desk.min(0)[0] >= 1.0 - 1e-6
    else:
        assert art.get("gaussians/labels") is None
    assert ("turned from y up" in output) == (suffix in (".gltf", ".glb"))


def test_obj_without_groups_is_unlabelled_and_labels_drive_room_preset(tmp_path):
    art, _ = read_back(write_obj(tmp_path / "plain.obj", groups=False))
    assert art.get("gaussians/labels") is None
    art, output = read_back(write_obj(tmp_path / "plain.obj", groups=False), "--preset", "room")
    assert "no labels (one object per label), so --preset room goes without --object-cells and " \
           "--drop-contact-faces (every face at --spacing 0.5" in output
    assert "left out" not in output and art.get("gaussians/labels") is None
    result = runner.invoke(app, ["mesh-gaussians", str(tmp_path / "plain.obj"), "-o", str(tmp_path / "p.h5"),
                                 "--preset", "room", "--object-cells", "12"])     # asked for: refused
    assert result.exit_code == 2 and "--object-cells needs a per-face 'label'" in result.output
    assert not (tmp_path / "p.h5").exists()
    # with groups the room preset's object cells and dropped contact faces work: the desk's bottom rests on the floor
    art, output = read_back(write_obj(tmp_path / "room.obj"), "--preset", "room")
    assert "left out 2 faces" in output and "desk_00 2" in output and "(preset room)" in output
    assert abs(area_of(art) - (ROOM_AREA + DESK_AREA - 1.2 * 0.6)) < 1e-3 * ROOM_AREA


def test_open3d_gltf_is_read(tmp_path):
    """Open3D writes glTF without turning its coordinates to y up: --up z reads them as they are."""
    o3d = pytest.importorskip("open3d")
    box = o3d.geometry.TriangleMesh.create_box(3.0, 2.0, 2.5)
    assert o3d.io.write_triangle_mesh(str(tmp_path / "b.glb"), box)
    art, output = read_back(tmp_path / "b.glb", "--up", "z")
    np.testing.assert_allclose(art["gaussians/means"].max(0), ROOM[1], atol=0.26)
    assert "turned" not in output and abs(area_of(art) - ROOM_AREA) < 1e-3 * ROOM_AREA


@pytest.mark.parametrize("name, content, message", [
    ("room.3ds", b"x", "unknown mesh format '.3ds': rfir reads PLY (.ply), OBJ (.obj), STL (.stl), glTF (.gltf, .glb)"),
    ("room", b"x", "unknown mesh format '(no extension)'"),
    ("bad.obj", b"v 0 0 0\nv 1 0 0\nf 1 2 3\n", "line 3: face refers to vertex 3, but 2 vertices are defined"),
    ("bad.obj", b"v 0 0 zero\n", "line 1: a vertex needs three numbers"),
    ("empty.obj", b"# nothing\n", "OBJ has no faces"),
    ("bad.stl", b"hello", "not an STL file"),
    ("bad.gltf", b"{not json", "not a readable glTF file"),
    ("bad.glb", b"glTF" + struct.pack("<II", 1, 20), "GLB version 1"),
])
def test_bad_meshes_one_line(tmp_path, name, content, message):
    path = tmp_path / name
    path.write_bytes(content)
    result = runner.invoke(app, ["mesh-gaussians", str(path), "-o", str(tmp_path / "s.h5")])
    output = " ".join(result.output.split())
    assert result.exit_code == 2 and message in output, result.output
    assert "Traceback" not in result.output and len(result.output.strip().splitlines()) <= 3
    assert not (tmp_path / "s.h5").exists()


def test_presets_and_flags_that_override_them(tmp_path):
    from rfir_cli.commands.mesh_gaussians import preset_values
    from rfir_core.errors import ConfigError

    assert preset_values("room", None, None, None, None) == (0.8, 12, True, True)
    assert preset_values("object", None, None, None, None) == (0.03, 0, False, False)
    assert preset_values(None, None, None, None, None) == (0.03, 0, False, False)
    assert preset_values("room", 0.4, 0, False, None) == (0.4, 0, False, True)
    with pytest.raises(ConfigError, match="--preset must be one of room, object"):
        preset_values("rooms", None, None, None, None)
    path = write_obj(tmp_path / "room.obj")
    _, output = read_back(path, "--preset", "room", "--no-rectangles")     # read_back adds --spacing 0.5
    assert "at 50 cm spacing" in output and "rectangles tiled" not in output and "(preset room)" in output
    _, output = read_back(path, "--preset", "room", "--no-drop-contact-faces")
    assert "left out" not in output and "rectangles tiled" in output


def test_room_without_preset_warns_before_tiling(tmp_path, monkeypatch):
    """No --preset and no --spacing on a room: the object tiling's count is estimated and a warning names
    --preset room; on the desk alone (small) nothing is said."""
    from rfir_cli.commands import mesh_gaussians
    from rfir_stages.geom.mesh_formats import read_mesh

    path = write_obj(tmp_path / "room.obj")
    assert mesh_gaussians.estimated_count(read_mesh(path), 0.03) > mesh_gaussians.LARGE_COUNT
    assert mesh_gaussians.estimated_count(read_mesh(path), 0.8) < 1000
    result = runner.invoke(app, ["mesh-gaussians", str(path), "-o", str(tmp_path / "s.h5"), "--spacing", "0.3"])
    assert result.exit_code == 0 and "--preset room" not in result.output   # a spacing chosen: no warning
    desk = tmp_path / "desk.obj"
    desk.write_text("o desk\n" + "\n".join(f"v {x} {y} {z}" for x, y, z in corners(*DESK)) + "\n"
                    + "\n".join("f " + " ".join(str(c + 1) for c in q) for q in QUADS) + "\n")
    result = runner.invoke(app, ["mesh-gaussians", str(desk), "-o", str(tmp_path / "d.h5")])
    assert result.exit_code == 0 and "warning" not in result.output
    assert "(no --preset" in " ".join(result.output.split())
    count = mesh_gaussians.estimated_count(read_mesh(desk), 0.03)
    monkeypatch.setattr(mesh_gaussians, "LARGE_COUNT", count - 1)       # the desk as if it were a room
    result = runner.invoke(app, ["mesh-gaussians", str(desk), "-o", str(tmp_path / "d2.h5")])
    output = " ".join(result.output.split())
    assert result.exit_code == 0 and f"warning: no --preset: the object tiling at 3 cm makes up to {count:,}" in output
    assert "use --preset room" in output
