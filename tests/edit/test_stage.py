"""`rfir edit` end to end on a two-box scene: inverses, delete vs a scene without, history, bad input."""

import numpy as np
import pytest
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact
from rfir_cli.main import app
from rfir_stages.edit import run
from rfir_stages.edit.script import edits_from_options
from rfir_stages.predict.rcs import predict_path_gain_db

runner = CliRunner()
CHAIR = "box:0.1,-1,-1,1,1,1"  # the box at x = +0.2 m


def _gains(path) -> np.ndarray:
    """Monostatic path gain [12, 1] dB of an rf artifact, radar at 3 m around the z axis."""
    a = np.radians(np.arange(0, 360, 30))
    tx = np.stack([3 * np.cos(-a), 3 * np.sin(-a), np.full_like(a, 0.001)], 1)
    return predict_path_gain_db(read_artifact(path, "rf"), tx, tx - [0, 0, 0.002], [10e9], "rcs")


def _edit(*args):
    return runner.invoke(app, ["edit", *map(str, args)])


def _all_arrays(path) -> dict:
    art = read_artifact(path, "rf")
    out = dict(art.data)
    out.update({f"model/{k}": v for k, v in art.free["model"].items()})
    return out


def test_translate_then_inverse_gives_back_arrays_and_predictions(rf_path, tmp_path):
    moved, back = tmp_path / "moved.h5", tmp_path / "back.h5"
    r = _edit(rf_path, "-o", moved, "--select", CHAIR, "--op", "translate:0.3,0.1,0")
    assert r.exit_code == 0, r.output
    hist = read_artifact(moved, "rf").provenance.extra["edits"]
    per_box = int((read_artifact(rf_path, "rf")["gaussians/labels"] == 1).sum())
    assert len(hist) == 1 and hist[0]["selected"] == per_box and hist[0]["inverse"].startswith("translate:-0.3")
    assert not np.allclose(_gains(moved), _gains(rf_path), atol=1e-3)
    r = _edit(moved, "-o", back, "--select", "box:0.4,-1,-1,1,1,1", "--op", hist[0]["inverse"])
    assert r.exit_code == 0, r.output
    a, b = _all_arrays(rf_path), _all_arrays(back)
    assert a.keys() == b.keys()
    for k in a:
        assert np.allclose(a[k], b[k], rtol=0, atol=1e-12), k
    assert np.max(np.abs(_gains(back) - _gains(rf_path))) < 1e-9
    assert len(read_artifact(back, "rf").provenance.extra["edits"]) == 2  # history appended


def test_rotate_then_inverse_gives_back_predictions(rf_path, tmp_path):
    res = run(rf_path, tmp_path / "r.h5", edits_from_options([CHAIR], ["rotate:0,1,1,37"]))
    inv = res.records[0]["inverse"]
    run(tmp_path / "r.h5", tmp_path / "b.h5", edits_from_options(["label:chair"], [inv]))
    assert np.max(np.abs(_gains(tmp_path / "b.h5") - _gains(rf_path))) < 1e-9


def test_delete_then_predict_equals_scene_without(rf_path, tmp_path, write_rf):
    r = _edit(rf_path, "-o", tmp_path / "del.h5", "--select", "label:chair", "--op", "delete")
    assert r.exit_code == 0, r.output
    labels = read_artifact(rf_path, "rf")["gaussians/labels"]
    without = write_rf(tmp_path / "without.h5", keep=labels == 0)
    a, b = _all_arrays(tmp_path / "del.h5"), _all_arrays(without)
    assert a.keys() == b.keys()
    for k in a:
        assert np.array_equal(a[k], b[k]), k
    assert np.array_equal(_gains(tmp_path / "del.h5"), _gains(without))


def test_script_duplicate_material_label_and_plot(rf_path, tmp_path):
    script = tmp_path / "edits.toml"
    script.write_text('[[edit]]\nselect = "label:crate"\nop = "duplicate:0,0.5,0"\n'
                      '[[edit]]\nselect = "box:-1,0.3,-1,1,1,1"\nop = "label:crate_copy"\nnote = "name the copy"\n'
                      '[[edit]]\nselect = "label:crate_copy"\nop = "material:metal"\n')
    out, png = tmp_path / "dup.h5", tmp_path / "dup.png"
    r = _edit(rf_path, "-o", out, "--script", script, "--plot", png)
    assert r.exit_code == 0, r.output
    art, src = read_artifact(out, "rf"), read_artifact(rf_path, "rf")
    per_box = int((src["gaussians/labels"] == 0).sum())
    assert len(art["gaussians/means"]) == 3 * per_box and list(art.attrs["label_names"]) == ["crate", "chair", "crate_copy"]
    copy = art["gaussians/labels"] == 2
    assert copy.sum() == per_box and np.all(art["material/index"][copy] == 2) and art["material/eps_r"].shape == (3,)
    assert np.all(art["rf/gamma_abs"][copy] > 0.99) and np.all(art["material/index"][~copy] == src["material/index"])
    assert np.array_equal(art.free["model"]["tag"][copy], src.free["model"]["tag"][:per_box])
    assert np.array_equal(art["gaussians/means"][copy], src["gaussians/means"][:per_box] + [0, 0.5, 0])
    assert [e["note"] for e in art.provenance.extra["edits"]][1] == "name the copy"
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert "moved outside the scene bounds" in r.output


def test_dry_run_lists_and_writes_nothing(rf_path, tmp_path):
    r = _edit(rf_path, "--dry-run", "--select", "label:chair", "--select", "sphere:-0.2,0,0,0.03")
    assert r.exit_code == 0, r.output
    per_box = int((read_artifact(rf_path, "rf")["gaussians/labels"] == 1).sum())
    assert f"label:chair selects {per_box}" in r.output and "nothing written" in r.output
    assert list(tmp_path.iterdir()) == [rf_path]


@pytest.mark.parametrize("args, code, message", [
    (["--select", "sphere:5,5,5,0.1", "--op", "delete"], 4, "selects none of 600"),
    (["--select", "all", "--op", "delete"], 5, "deletes every Gaussian"),
    (["--select", "all"], 4, "is required unless --dry-run"),
    (["--select", "all", "--select", "all", "--op", "delete"], 4, "one --select per --op"),
    (["--select", "label:sofa", "--op", "delete"], 4, "no label named 'sofa'"),
    (["--select", "all", "--op", "explode"], 4, "unknown operation 'explode'"),
])
def test_bad_input_one_line_and_exit_code(rf_path, tmp_path, args, code, message):
    out = tmp_path / "out.h5"
    r = _edit(rf_path, *(["-o", out] if "required" not in message else []), *args)
    assert r.exit_code == code, r.output
    assert message in r.output.replace("\n", " ") and "Traceback" not in r.output
    assert not out.exists()


def test_allow_empty_skips_the_edit(rf_path, tmp_path):
    r = _edit(rf_path, "-o", tmp_path / "o.h5", "--allow-empty", "--select", "sphere:5,5,5,0.1", "--op", "delete")
    assert r.exit_code == 0, r.output
    assert np.array_equal(_all_arrays(tmp_path / "o.h5")["gaussians/means"], _all_arrays(rf_path)["gaussians/means"])


def test_refuses_output_equal_to_input(rf_path):
    before = rf_path.read_bytes()
    r = _edit(rf_path, "-o", rf_path, "--select", "all", "--op", "translate:1,0,0")
    assert r.exit_code == 4 and "refusing to overwrite the input" in r.output
    assert rf_path.read_bytes() == before


def test_script_unknown_key_is_named(rf_path, tmp_path):
    script = tmp_path / "bad.toml"
    script.write_text('[[edit]]\nselect = "all"\nop = "delete"\nslect = "typo"\n')
    r = _edit(rf_path, "-o", tmp_path / "o.h5", "--script", script)
    assert r.exit_code == 4 and "unknown key 'slect'" in r.output
    script.write_text('version = 2\n[[edit]]\nselect = "all"\nop = "delete"\n')
    r = _edit(rf_path, "-o", tmp_path / "o.h5", "--script", script)
    assert r.exit_code == 4 and "unknown key 'version'" in r.output


def test_output_passes_rfir_check_and_new_labels_do_not_reuse_ids(tmp_path, write_rf):
    from rfir_core.artifacts import validate_artifact, write_artifact

    art = read_artifact(write_rf(tmp_path / "a.h5"), "rf")
    attrs = {"task": "rcs"}  # labels without label_names: ids 0 and 1 must stay unnamed-but-distinct
    free = {"model": {**art.free["model"], "@attrs": dict(art.free["model@attrs"])}}
    write_artifact(tmp_path / "nolabels.h5", "rf", art.data, attrs=attrs, free=free)
    out = tmp_path / "o.h5"
    run(tmp_path / "nolabels.h5", out, edits_from_options(["sphere:0.2,0,0,0.06"], ["label:lid"]))
    assert validate_artifact(out, "rf") == []
    edited = read_artifact(out, "rf")
    assert list(edited.attrs["label_names"]) == ["label_0", "label_1", "lid"]
    assert set(np.unique(edited["gaussians/labels"])) == {0, 1, 2}


def test_free_group_arrays_of_length_g_travel_known_others_stay(tmp_path, write_rf):
    from rfir_core.artifacts import write_artifact

    art = read_artifact(write_rf(tmp_path / "a.h5"), "rf")
    g = len(art["gaussians/means"])
    extra = np.arange(2 * g, dtype=float).reshape(g, 2)
    free = {"model": {**art.free["model"], "per_gaussian.x": extra, "device_tx_gain_db": np.zeros(g),
                      "@attrs": art.free["model@attrs"]},
            "training": {"loss_curve": np.zeros(g), "fit_rows": np.arange(g)}}
    write_artifact(tmp_path / "b.h5", "rf", art.data, attrs=dict(art.attrs), free=free)
    run(tmp_path / "b.h5", tmp_path / "o.h5", edits_from_options(["label:chair"], ["delete"]))
    out = read_artifact(tmp_path / "o.h5", "rf")
    keep = art["gaussians/labels"] == 0
    assert np.array_equal(out.free["model"]["per_gaussian.x"], extra[keep])
    assert out.free["model"]["device_tx_gain_db"].shape == (g,) and out.free["training"]["loss_curve"].shape == (g,)
    assert out.free["training"]["fit_rows"].shape == (g,)
    assert out.free["model@attrs"]["antenna_kind"] == "isotropic"


def test_plot_adds_the_rcs_change_of_an_rcs_model(rf_path, tmp_path):
    from rfir_stages.edit import run
    from rfir_stages.edit.script import edits_from_options

    plot = tmp_path / "edit.png"
    res = run(rf_path, tmp_path / "out.h5", edits_from_options(["label:chair"], ["delete"], False), plot_path=plot)
    assert res.radio_plot == tmp_path / "edit_radio.png" and res.radio_plot.stat().st_size > 1000
    assert res.radio_change["mean_abs_change_db"] > 0.1 and res.radio_change["points"] == 360
    same = run(rf_path, tmp_path / "same.h5", edits_from_options(["label:chair"], ["translate:0,0,0"], False),
               plot_path=tmp_path / "same.png")
    assert same.radio_change["max_abs_change_db"] < 1e-9


def test_an_edit_drops_the_link_space_residual_and_predicts_the_physics_alone(tmp_path):
    """A smooth residual corrects the unedited scene's training links in link geometry; after an edit the
    model predicts the physics alone (docs/guide/edit.md)."""
    from rfir_core.artifacts import write_artifact
    from rfir_stages.model.residual import ResidualFit, residual_fields

    from .conftest import two_boxes

    data, free = two_boxes()
    a = np.radians(np.arange(0, 360, 30))
    tx = np.stack([3 * np.cos(-a), 3 * np.sin(-a), np.full_like(a, 0.001)], 1)
    fit = ResidualFit("smooth", {"weights_db": np.full((12, 1), 3.0), "mean_db": np.zeros(1), "length_deg": 20.0,
                                 "range_length": 1.0, "weight": 0.3}, chosen="smooth l=20 deg")
    r_data, r_attrs = residual_fields(fit, tx, tx - [0, 0, 0.002])
    data.update(r_data)
    free["model"]["@attrs"].update(r_attrs)
    attrs = {"task": "rcs", "label_names": np.asarray(["crate", "chair"], dtype=object)}
    with_res = write_artifact(tmp_path / "res.h5", "rf", data, attrs=attrs, free=free)
    plain = write_artifact(tmp_path / "plain.h5", "rf", two_boxes()[0], attrs=attrs, free=two_boxes()[1])
    assert np.min(_gains(with_res) - _gains(plain)) > 1.0          # the residual lifts every link
    said = {}
    for path, out in ((with_res, tmp_path / "e_res.h5"), (plain, tmp_path / "e_plain.h5")):
        r = _edit(path, "-o", out, "--select", "label:chair", "--op", "translate:0,0.1,0")
        assert r.exit_code == 0, r.output
        said[out.name] = " ".join(r.output.split())
    assert "residual" in said["e_res.h5"] and "dropped" in said["e_res.h5"]
    assert "residual" not in said["e_plain.h5"]
    edited = read_artifact(tmp_path / "e_res.h5", "rf")
    assert edited.free["model@attrs"]["residual.form"] == "off"
    assert not any(k.startswith("residual.") and k not in ("residual.form", "residual.chosen")
                   for k in edited.free["model@attrs"])
    assert not any(k.startswith("residual/") for k in edited.data)
    assert np.max(np.abs(_gains(tmp_path / "e_res.h5") - _gains(tmp_path / "e_plain.h5"))) < 1e-9


def test_links_ranges_of_fitted_materials_survive_a_move_but_not_a_new_material(rf_path, tmp_path):
    """material/gamma_normal_range describes the fitted materials: a move keeps it, material:NAME (an ITU
    material the links never saw) drops it rather than leave a row-count mismatch or a made-up range."""
    import shutil

    import h5py
    src = tmp_path / "rf_ranges.h5"
    shutil.copy(rf_path, src)
    with h5py.File(src, "r+") as h:
        n = len(h["material/eps_r"])
        h["material/gamma_normal_range"] = np.tile([0.2, 0.6], (n, 1))
    moved, metal = tmp_path / "moved.h5", tmp_path / "metal.h5"
    assert _edit(src, "-o", moved, "--select", "label:crate", "--op", "translate:0,0.1,0").exit_code == 0
    assert _edit(src, "-o", metal, "--select", "label:crate", "--op", "material:metal").exit_code == 0
    assert np.array_equal(read_artifact(moved, "rf")["material/gamma_normal_range"], np.tile([0.2, 0.6], (n, 1)))
    assert read_artifact(metal, "rf").get("material/gamma_normal_range") is None


def test_material_edit_states_the_values_it_assumed(rf_path, tmp_path):
    """material:NAME prints (and keeps in the history) the ITU values at the model's frequency and the
    thickness and S it keeps from the material it replaces; re-materialling twice keeps the first's."""
    from rfir_core.physics.materials import itu_law

    out = tmp_path / "e.h5"
    r = _edit(rf_path, "-o", out, "--select", "label:crate", "--op", "material:metal",
              "--select", "label:crate", "--op", "material:glass")
    assert r.exit_code == 0, r.output
    text = " ".join(r.output.split())
    eps, sigma = itu_law("glass", 10e9)
    assert "ITU-R P.2040 metal at 10 GHz: eps_r 1, sigma 1e+07 S/m; thickness 20 mm and S 0.10 kept from crate" in text
    assert (f"ITU-R P.2040 glass at 10 GHz: eps_r {eps:.3g}, sigma {sigma:.3g} S/m; thickness 20 mm and S 0.10 kept "
            "from crate") in text
    art = read_artifact(out, "rf")
    assert np.allclose(art["material/scattering"], [0.1, 0.3, 0.1, 0.1])
    assert np.allclose(art["material/thickness_m"], [0.02, 0.05, 0.02, 0.02])
    history = art.provenance.extra["edits"]
    assert "S 0.10 kept from crate" in history[0]["op"] and history[0]["op"].startswith("material:metal (")
