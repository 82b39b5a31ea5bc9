"""Edited ground-truth scenes (simulate.scene_edits), and their agreement with `rfir edit`."""
from __future__ import annotations

import numpy as np
import pytest

from rfir_core.errors import ConfigError
from rfir_stages.edit.operations import EditScene, apply, parse_operation
from rfir_stages.simulate.scene_edits import apply_scene_edits, rotation_matrix
from rfir_stages.simulate.scenes import build_scene
from rfir_stages.simulate.settings import parse_settings


def _by_name(spec):
    return {o.name: o for o in spec.objects}


def test_translate_moves_only_the_matched_objects():
    before, after = _by_name(build_scene("classroom")), build_scene("classroom")
    apply_scene_edits(after, ["desk_0[0369]|chair_0[0369]:translate:0,1,0"])
    moved = {n for n, o in _by_name(after).items() if not np.allclose(o.vertices, before[n].vertices)}
    assert moved == {f"{k}_{i:02d}" for k in ("desk", "chair") for i in (0, 3, 6, 9)}
    for n in moved:
        assert np.allclose(_by_name(after)[n].vertices - before[n].vertices, [0.0, 1.0, 0.0])


def test_rotate_is_rigid_about_the_pivot_and_matches_rfir_edit():
    before, spec = build_scene("lego"), build_scene("lego")
    apply_scene_edits(spec, ["brick_1[6-9]:rotate:0,0,1,45,0,0,0"])
    for o0, o1 in zip(before.objects, spec.objects):
        if o0.name in ("brick_16", "brick_17", "brick_18", "brick_19"):
            d0 = np.linalg.norm(o0.vertices[:, None] - o0.vertices[None], axis=-1)
            d1 = np.linalg.norm(o1.vertices[:, None] - o1.vertices[None], axis=-1)
            assert np.allclose(d0, d1) and not np.allclose(o0.vertices, o1.vertices)
            assert np.allclose(o0.vertices[:, 2], o1.vertices[:, 2])      # about z: heights stay
            # the same edit through rfir edit's operation, on points at the mesh vertices
            n = len(o0.vertices)
            scene = EditScene({"gaussians/means": o0.vertices.copy(), "gaussians/normals": np.tile([1.0, 0, 0], (n, 1)),
                               "gaussians/rotations": np.tile([1.0, 0, 0, 0], (n, 1))}, [])
            apply(scene, np.ones(n, bool), parse_operation("rotate:0,0,1,45,0,0,0"))
            assert np.allclose(scene.arrays["gaussians/means"], o1.vertices, atol=1e-12)
        else:
            assert np.array_equal(o0.vertices, o1.vertices)
    r = rotation_matrix([0, 0, 1], 90)
    assert np.allclose(r @ [1, 0, 0], [0, 1, 0])                              # right-handed


def test_delete_renumbers_labels_and_material_swaps():
    spec = build_scene("classroom")
    n = len(spec.objects)
    apply_scene_edits(spec, ["whiteboard:delete", "wall_back:material:metal"])
    names = [o.name for o in spec.objects]
    assert "whiteboard" not in names and len(names) == n - 1
    assert [o.label for o in spec.objects] == list(range(n - 1))
    assert _by_name(spec)["wall_back"].radio_material == "metal"
    assert _by_name(spec)["wall_front"].radio_material == "concrete"


@pytest.mark.parametrize("edit, words", [
    ("whiteboard:explode", "unknown operation"),
    ("sofa:delete", "no object"),
    ("desk_00:translate:1,2", "expected 3 numbers"),
    ("desk_00:rotate:0,0,0,30", "axis is zero"),
    ("wall_back:material:unobtainium", "unknown radio material"),
])
def test_bad_edits_name_the_edit(edit, words):
    with pytest.raises(ConfigError) as err:
        apply_scene_edits(build_scene("classroom"), [edit])
    assert words in str(err.value) and edit in str(err.value)


def test_settings_carry_the_edits():
    s = parse_settings({"scene_edits": ["whiteboard:delete"]})
    assert s.scene_edits == ["whiteboard:delete"]
    assert parse_settings(None).scene_edits == []
