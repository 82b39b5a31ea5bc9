"""Faces that rest against another object's surface (a box's bottom on the floor) are found and left out."""
import json
import math

import h5py
import numpy as np
from typer.testing import CliRunner

from rfir_cli.main import app
from rfir_stages.geom.contact_faces import contact_faces
from rfir_stages.simulate.scenes import box, rect_xy

from .test_mesh_gaussians import write_ply


def _scene(*parts):
    """(vertices, faces, labels) of (vertices, faces) parts, part k labelled k."""
    vs, fs, ls, off = [], [], [], 0
    for k, (v, f) in enumerate(parts):
        vs.append(np.asarray(v, float))
        fs.append(np.asarray(f) + off)
        ls.append(np.full(len(f), k))
        off += len(v)
    return np.concatenate(vs), np.concatenate(fs), np.concatenate(ls)


def _rotation(axis, deg):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = math.radians(deg)
    return np.eye(3) + math.sin(a) * k + (1 - math.cos(a)) * k @ k


def _bottom(v, f, lo_z=0.0):
    """[F] bool: faces whose three vertices are at height lo_z."""
    return np.all(np.abs(v[f][:, :, 2] - lo_z) < 1e-9, axis=1)


FLOOR = rect_xy(0.0, 4.0, 0.0, 3.0, 0.0, up=True)


def test_a_box_on_the_floor_loses_its_bottom_and_the_floor_stays():
    v, f, lab = _scene(FLOOR, box((1.0, 1.0, 0.0), (1.7, 2.8, 0.76)))
    got = contact_faces(v, f, lab)
    assert got.sum() == 2 and np.all(got == (_bottom(v, f) & (lab == 1)))
    # the same turned out of the axes and moved: the planes found without axis-aligned coordinates
    rot = _rotation([1, 2, 3], 33.0)
    assert np.array_equal(contact_faces(v @ rot.T + [0.3, -2.0, 5.0], f, lab), got)


def test_no_contact_without_touching_or_without_labels_or_within_one_object():
    v, f, lab = _scene(FLOOR, box((1.0, 1.0, 0.002), (1.7, 2.8, 0.76)))     # 2 mm above the floor
    assert not contact_faces(v, f, lab).any()
    assert contact_faces(v, f, lab, tol_m=0.003).sum() == 2                  # within a 3 mm tolerance it rests
    v, f, lab = _scene(FLOOR, box((1.0, 1.0, 0.0), (1.7, 2.8, 0.76)))
    assert not contact_faces(v, f, None).any()                               # an unlabelled mesh: left as it is
    assert not contact_faces(v, f, np.zeros_like(lab)).any()                 # one object's own faces: kept
    # a plate modelled as two back-to-back faces of one object is kept too
    plate = _scene(rect_xy(0, 1, 0, 1, 0.5, up=True), rect_xy(0, 1, 0, 1, 0.5, up=False))
    assert not contact_faces(plate[0], plate[1], np.zeros(4, np.int64)).any()


def test_a_box_over_the_floors_edge_keeps_its_bottom():
    v, f, lab = _scene(FLOOR, box((3.5, 1.0, 0.0), (4.3, 1.8, 0.5)))        # 0.3 m beyond the floor's edge
    assert not contact_faces(v, f, lab).any()


def test_two_boxes_side_by_side_lose_the_faces_between_them():
    v, f, lab = _scene(FLOOR, box((1.0, 1.0, 0.0), (1.5, 1.6, 0.9)), box((1.5, 1.0, 0.0), (2.0, 1.6, 0.9)))
    got = contact_faces(v, f, lab)
    between = np.all(np.abs(v[f][:, :, 0] - 1.5) < 1e-9, axis=1)
    assert np.array_equal(got, (_bottom(v, f) & (lab > 0)) | between) and between.sum() == 4


def test_mesh_gaussians_leaves_them_out_and_says_so(tmp_path):
    v, f, lab = _scene(FLOOR, box((1.0, 1.0, 0.0), (1.7, 2.8, 0.76)))
    write_ply(tmp_path / "room.ply", v, f, lab)
    (tmp_path / "labels.json").write_text(json.dumps({"objects": [{"label": 0, "name": "floor"},
                                                                  {"label": 1, "name": "block"}]}))
    counts = {}
    for extra in (["--drop-contact-faces"], []):
        out = tmp_path / f"s{len(extra)}.h5"
        r = CliRunner().invoke(app, ["mesh-gaussians", str(tmp_path / "room.ply"), "-o", str(out), "--spacing", "0.2",
                                     *extra], terminal_width=200)
        assert r.exit_code == 0, r.output
        assert ("left out 2 faces that rest against another object's surface" in r.output) == bool(extra)
        assert extra or "left out" not in r.output
        with h5py.File(out) as h5:
            means, normals, labels = (np.asarray(h5[f"gaussians/{k}"]) for k in ("means", "normals", "labels"))
        counts[not extra] = int(((labels == 1) & (normals[:, 2] < -0.9)).sum())
        assert ((labels == 0) & (normals[:, 2] > 0.9)).sum() > 0                  # the floor is kept
        assert np.all(np.abs(means[(labels == 1) & (normals[:, 2] < -0.9), 2]) < 1e-9)
    assert counts[False] == 0 and counts[True] > 0
    r = CliRunner().invoke(app, ["mesh-gaussians", str(write_ply(tmp_path / "bare.ply", v, f)), "-o",
                                 str(tmp_path / "bare.h5"), "--drop-contact-faces"], terminal_width=200)
    assert r.exit_code != 0 and "needs a per-face 'label'" in r.output and "Traceback" not in r.output
    assert not (tmp_path / "bare.h5").exists()
