"""Pure selection and operation tests: geometric invariants, inverses, parsing errors."""
import math

import numpy as np
import pytest

from rfir_core.errors import ConfigError
from rfir_stages.edit.operations import EditScene, apply, covariances, parse_operation, quat_to_matrix
from rfir_stages.edit.selection import parse_selection


def _scene(g=50, seed=1) -> EditScene:
    rng = np.random.default_rng(seed)
    q = rng.normal(size=(g, 4))
    n = rng.normal(size=(g, 3))
    return EditScene({"gaussians/means": rng.uniform(-1, 1, (g, 3)), "gaussians/log_scales": rng.uniform(-5, -1, (g, 3)),
                      "gaussians/rotations": q / np.linalg.norm(q, axis=1, keepdims=True),
                      "gaussians/normals": n / np.linalg.norm(n, axis=1, keepdims=True),
                      "rf/opacity": rng.uniform(0, 1, g), "rf/roughness": rng.uniform(1, 9, g),
                      "rf/gamma_abs": rng.uniform(0, 1, g), "rf/gamma_phase_rad": rng.uniform(-3, 3, g),
                      "material/index": rng.integers(0, 2, g)}, num_materials=2)


def test_rotation_keeps_covariances_positive_definite_and_normals_unit():
    s = _scene()
    before = {k: v.copy() for k, v in s.arrays.items()}
    mask = s.arrays["gaussians/means"][:, 0] > 0
    rec = apply(s, mask, parse_operation("rotate:1,2,3,73,0.1,0.2,0.3"))
    a = s.arrays
    cov = covariances(a["gaussians/log_scales"], a["gaussians/rotations"])
    assert np.all(np.linalg.eigvalsh(cov) > 0)
    assert np.allclose(np.linalg.norm(a["gaussians/normals"], axis=1), 1, atol=1e-12)
    assert np.allclose(np.linalg.norm(a["gaussians/rotations"], axis=1), 1, atol=1e-12)
    # the covariance turns with the rotation: R Sigma R^T; means turn about the pivot; distances kept
    axis = np.array([1, 2, 3]) / math.sqrt(14)
    rot = quat_to_matrix(np.concatenate([[math.cos(math.radians(36.5))], math.sin(math.radians(36.5)) * axis]))
    old = covariances(before["gaussians/log_scales"], before["gaussians/rotations"])
    assert np.allclose(cov[mask], rot @ old[mask] @ rot.T, atol=1e-14)
    assert np.allclose(cov[~mask], old[~mask], atol=0)
    pivot = np.array([0.1, 0.2, 0.3])
    assert np.allclose(a["gaussians/means"][mask] - pivot, (before["gaussians/means"][mask] - pivot) @ rot.T)
    assert np.allclose(a["gaussians/normals"][mask], before["gaussians/normals"][mask] @ rot.T)
    # the normal keeps its place in the Gaussian's local frame
    local = lambda q, n: np.einsum("gji,gj->gi", quat_to_matrix(q), n)  # noqa: E731
    assert np.allclose(local(a["gaussians/rotations"], a["gaussians/normals"]),
                       local(before["gaussians/rotations"], before["gaussians/normals"]), atol=1e-12)
    apply(s, mask, parse_operation(rec["inverse"]))
    for k in before:
        assert np.allclose(s.arrays[k], before[k], atol=1e-12), k


def test_rotate_default_pivot_is_the_selection_centroid():
    s = _scene()
    mask = np.arange(s.count) < 10
    centroid = s.arrays["gaussians/means"][mask].mean(0)
    rec = apply(s, mask, parse_operation("rotate:0,0,1,90"))
    assert np.allclose(s.arrays["gaussians/means"][mask].mean(0), centroid)
    assert rec["op"].startswith("rotate:0.0,0.0,1.0,90.0,") and rec["inverse"].startswith("rotate:0.0,0.0,1.0,-90.0,")


def test_delete_duplicate_carry_every_array_and_material_appends_one():
    s = _scene(g=20)
    before = {k: v.copy() for k, v in s.arrays.items()}
    mask = np.zeros(20, bool)
    mask[[2, 5]] = True
    apply(s, mask, parse_operation("duplicate:1,0,0"))
    assert s.count == 22 and s.touched[20:].all()
    for k in before:
        expect = before[k][[2, 5]] + ([1, 0, 0] if k == "gaussians/means" else 0)
        assert np.array_equal(s.arrays[k][20:], expect), k
    apply(s, np.arange(22) >= 20, parse_operation("delete"))
    for k in before:
        assert np.array_equal(s.arrays[k], before[k]), k
    apply(s, mask, parse_operation("material:metal"))
    # the selection gets a new material (index 2, after the model's two); nothing else changes
    assert np.all(s.arrays["material/index"][mask] == 2) and s.touched[mask].all() and not s.touched[~mask].any()
    assert np.array_equal(s.arrays["material/index"][~mask], before["material/index"][~mask])
    assert s.new_materials == [("metal", int(np.bincount(before["material/index"][mask]).argmax()))]
    for k in before:
        if k != "material/index":
            assert np.array_equal(s.arrays[k], before[k]), k


def test_selections():
    p = np.array([[0, 0, 0], [0.9, 0, 0], [0.6, 0.6, 0], [2, 2, 2]], float)
    assert parse_selection("box:-1,-1,-1,1,1,1").mask(p).tolist() == [True, True, True, False]
    assert parse_selection("sphere:0,0,0,0.85").mask(p).tolist() == [True, False, True, False]
    # a thin box along the x=y diagonal: only points near that line
    assert parse_selection("obox:0,0,0,1,0.1,0.1,45").mask(p).tolist() == [True, False, True, False]
    assert parse_selection("all").mask(p).all()
    labels, names = np.array([0, 1, 2, -1]), ["chair_0", "chair_1", "table"]
    assert parse_selection("label:chair_*").mask(p, labels, names).tolist() == [True, True, False, False]
    assert parse_selection("label:2").mask(p, labels, names).tolist() == [False, False, True, False]
    with pytest.raises(ConfigError, match="no label named 'sofa'"):
        parse_selection("label:sofa").mask(p, labels, names)
    with pytest.raises(ConfigError, match="no gaussians/labels"):
        parse_selection("label:sofa").mask(p)


@pytest.mark.parametrize("text, message", [("cube:1,2", "unknown selection 'cube'"), ("box:1,2,3", "box takes 6"),
                                           ("sphere:0,0,0,-1", "positive"), ("box:1,0,0,0,1,1", "minimum exceeds"),
                                           ("sphere:0,0,x,1", "comma-separated numbers")])
def test_bad_selections(text, message):
    with pytest.raises(ConfigError, match=message):
        parse_selection(text)


@pytest.mark.parametrize("text, message", [("spin:1", "unknown operation 'spin'"), ("translate:1,2", "translate takes 3"),
                                           ("material:unobtainium", "unobtainium"), ("rotate:0,0,0,90", "axis"),
                                           ("delete:3", "no arguments"), ("label:", "expected label:NAME")])
def test_bad_operations(text, message):
    with pytest.raises(ConfigError, match=message):
        parse_operation(text)


@pytest.mark.parametrize("text", ["set:gamma_abs=0.3,R=4", "scale:a=2", "SET:a=1", "scale:"])
def test_set_and_scale_are_refused_in_one_line_pointing_to_material(text):
    with pytest.raises(ConfigError) as err:
        parse_operation(text)
    message = str(err.value)
    assert "\n" not in message and repr(text) in message and "material:NAME" in message, message


def test_per_material_arrays_stay_when_there_are_as_many_materials_as_gaussians():
    from rfir_stages.edit.stage import per_gaussian_keys

    class _Art:   # the two parts of an artifact per_gaussian_keys reads
        def __init__(self, data, free):
            self.data, self.free = data, free

        def __getitem__(self, key):
            return self.data[key]

    g = 3   # three Gaussians, three materials: lengths alone cannot tell the arrays apart
    data = {"gaussians/means": np.zeros((g, 3)), "material/index": np.arange(g), "material/area_m2": np.ones(g),
            "material/eps_r": np.ones(g), "material/sigma_1ghz_s_per_m": np.ones(g),
            "material/scattering": np.ones(g), "material/thickness_m": np.ones(g),
            "material/gamma_normal_abs": np.ones((g, 1)), "rf/freq_hz": np.ones(g)}
    fields, free = per_gaussian_keys(_Art(data, {"residual": {"surfel": np.ones((g, 2)), "tx_pos": np.ones((g, 3))}}))
    assert set(fields) == {"gaussians/means", "material/index", "material/area_m2"}
    assert free == [("residual", "surfel")]
