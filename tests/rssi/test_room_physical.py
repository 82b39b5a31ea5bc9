"""The physical room model (what rf-fit fits to RSSI data) end to end on the reduced room.

The measurements are the independent closed form of helpers.py (Friis, an 8 dB partition, a floor
image with coefficient -0.4): the fitted model must predict the held-out links better than a fitted
log-distance model, and the partition's fitted material must cost about the 8 dB the data hold."""
import json
import math
import re

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from rfir_core.artifacts import read_artifact
from rfir_cli.main import app
from rfir_stages.model.artifact import load_physical
from rfir_core.physics.materials import C0, ITU_MATERIALS, slab_transmission

from .helpers import write_measurements, write_scene

PHYSICAL = ["--set", "rf_fit.physical.iterations=60",
            "--set", "rf_fit.physical.start_iterations=15"]


@pytest.fixture(scope="module")
def fitted(tmp_path_factory):
    d = tmp_path_factory.mktemp("room")
    write_scene(d / "scene.h5", spacing_m=0.3)
    write_measurements(d / "meas.h5")
    r = CliRunner().invoke(app, [*PHYSICAL, "rf-fit", str(d / "scene.h5"), str(d / "meas.h5"), "-o", str(d / "rf.h5")])
    assert r.exit_code == 0, r.output
    assert "physical room model" in r.output and "partition" in r.output     # assumptions and materials printed
    # the defaults that set the paths
    assert "patch extents tiles" in r.output and "reflections up to order 3" in r.output
    assert "order 2 off patches of at least 0.3 m^2, order 3 off patches of at least 1 m^2" in r.output
    out = " ".join(r.output.split())
    assert "(1 of them may be off patches of at least 0.3 m^2)" in out
    assert "the 3 best starting materials after 15 steps are each fitted to the end" in out
    assert ("at most 8 interactions per path (reflections and surfaces crossed; auto: the measurements record no "
            "simulator depth)") in out
    assert "planar patches (neighbours within 0.01 m of one plane joined)" in r.output    # exact surfels: no plane fit
    assert re.search(r"diffuse on \(\d+ cells of about 0.7 m, patches under 0.12 m\^2 pooled by material, facing and "
                     r"voxel; through the slabs it crosses\)", r.output)
    assert "tabulated materials tried in" in r.output and "tabulated one (ITU-R P.2040" in out
    return d


def test_fit_writes_materials_and_predicts_held_out_links(fitted, tmp_path):
    rf = read_artifact(fitted / "rf.h5", "rf")
    assert rf.free["model@attrs"]["model_kind"] == "rssi_physical"
    tabulated = [str(s) for s in np.atleast_1d(rf.free["model@attrs"]["material_tabulated"])]
    names = [str(s) for s in np.atleast_1d(rf.free["model@attrs"]["material_names"])]
    assert len(tabulated) == len(names) and set(tabulated) <= {"", *ITU_MATERIALS}
    info = CliRunner().invoke(app, ["info", str(fitted / "rf.h5")], terminal_width=200)
    assert info.exit_code == 0 and ("P.2040" in info.output) == any(tabulated)
    for name, key in zip(names, tabulated):
        if key:
            assert re.search(rf"{name}\b.*\b{key}\b", info.output)
    # the stored loss curve holds both steps of the fit (this room has third-order paths off patches under 1 m^2):
    # the winning start's 15 + 60 steps before the continuation's 60; one step alone holds at most 15 + 2 x 15 + 60
    assert len(np.asarray(rf.free["training"]["loss_curve"])) >= (15 + 60) + 60 > 15 + 2 * 15 + 60 - 1
    res = tmp_path / "res.json"
    r = CliRunner().invoke(app, ["predict", "rssi", str(fitted / "rf.h5"), "--measurements", str(fitted / "meas.h5"),
                                 "-o", str(tmp_path / "p.h5"), "--results", str(res), "--plots", str(tmp_path / "plots")])
    assert r.exit_code == 0, r.output
    m = json.loads(res.read_text())["metrics"]
    assert m["mae_db"] < 2.0
    assert m["mae_db"] < m["baseline_log_distance_mae_db"]
    assert {"rssi_predicted.png", "fov_attributes.png"} <= {p.name for p in (tmp_path / "plots").iterdir()}


def test_a_model_that_stores_no_small_reflections_loads_as_it_was_fitted(fitted, tmp_path):
    """A model written before third_order_small_reflections existed was fitted with the third order off large
    patches alone: it loads so (0), not with the current default; one that stores it, with its value."""
    import shutil

    import h5py

    from rfir_stages.model.room import RoomPredictor

    old = tmp_path / "old.h5"
    shutil.copy(fitted / "rf.h5", old)
    with h5py.File(old, "r+") as h:
        assert int(h["model"].attrs["room.third_order_small_reflections"]) == 1
        del h["model"].attrs["room.third_order_small_reflections"]
    assert RoomPredictor(read_artifact(old, "rf")).room.settings.third_order_small_reflections == 0
    assert RoomPredictor(read_artifact(fitted / "rf.h5", "rf")).room.settings.third_order_small_reflections == 1


def test_the_stored_patch_grids_load_the_patches_the_fit_built(fitted, tmp_path, monkeypatch):
    """rf-fit stores the patches' occupancy grids: the model loads them instead of rasterising, into the patch set
    a fresh build gives; a model whose Gaussians no longer match the key (an edit) rasterises again."""
    import shutil

    import h5py

    import rfir_stages.model.room_paths as room_paths
    from rfir_stages.model.room import RoomPredictor

    rasterised = []
    original = room_paths._tile_occupancy
    monkeypatch.setattr(room_paths, "_tile_occupancy", lambda *a, **k: rasterised.append(1) or original(*a, **k))
    rf = read_artifact(fitted / "rf.h5", "rf")
    assert "patch_grid" in rf.free["model"] and rf.free["model@attrs"]["patch_extents_key"]
    loaded = RoomPredictor(rf).room
    assert not rasterised                                           # nothing rasterised: the stored grids
    built = room_paths.build_patch_set(loaded.geom, loaded.areas, loaded.labels, loaded.settings.coplanar_m,
                                       extent=loaded.settings.patch_extent,
                                       merge_scatter_factor=loaded.settings.merge_scatter_factor)
    assert rasterised
    for name in ("normal", "point", "u", "v", "area", "label", "surfel_patch", "grid", "grid_offset", "grid_shape",
                 "grid_origin", "cell_m"):
        np.testing.assert_array_equal(getattr(loaded.patches, name), getattr(built, name), err_msg=name)
    moved = tmp_path / "moved.h5"
    shutil.copy(fitted / "rf.h5", moved)
    with h5py.File(moved, "r+") as h:
        h["gaussians/means"][0, 2] += 0.01
    rasterised.clear()
    RoomPredictor(read_artifact(moved, "rf"))
    assert rasterised                                               # key mismatch: rasterised again


def test_partition_material_costs_about_the_measured_wall_loss(fitted):
    rf = read_artifact(fitted / "rf.h5", "rf")
    model = load_physical(rf)
    i = model.names.index("partition")
    f = 2.4e9
    eta = model.mats.eta(torch.tensor([f]))[i, 0]
    t_te, _ = slab_transmission(eta, 1.0, 2 * math.pi * f / C0, model.mats.thickness_m[i])
    loss_db = -20 * float(np.log10(abs(complex(t_te))))
    assert 4.0 < loss_db < 12.0, loss_db


def test_material_names_give_itu_starting_values():
    from rfir_stages.rf_fit.room_stage import name_priors

    got = name_priors(["glass_partition", "desk", "Metal-Cabinet", "wall_concrete", "woodland"])
    assert set(got) == {0, 2, 3}                      # "woodland" is not wood, "desk" names no material
    assert got[0][0] == 6.31 and got[2][1] == 1e7 and got[3][2] == 0.2


def test_tabulated_step_decides_on_training_links_the_fit_did_not_use():
    from rfir_stages.rf_fit.room_stage import _check_links

    class Room:                                  # links() as the room's: returns what it was asked for
        def links(self, tx, rx, freq, axes=None):
            return tx, rx, freq

    tx, rx = np.arange(100.0)[:, None] * [1, 0, 0], np.zeros((100, 3))
    target = np.arange(100.0) - 50
    fit = np.linspace(0, 99, 30).round().astype(np.int64)
    (ctx, _, freq), ctarget = _check_links(Room(), tx, rx, fit, target, 2.4e9)
    rows = ctx[:, 0].astype(np.int64)
    assert len(rows) == 30 and not set(rows) & set(fit) and len(set(rows)) == 30    # as many, none fitted
    assert rows.max() - rows.min() > 80                                             # spread over the rest
    assert np.array_equal(ctarget[:, 0], target[rows]) and ctarget.shape == (30, 1) and np.all(freq == 2.4e9)
    few = np.setdiff1d(np.arange(100), [3, 7])                                      # fewer left than fitted
    assert sorted(_check_links(Room(), tx, rx, few, target, 2.4e9)[0][0][:, 0]) == [3, 7]
    assert _check_links(Room(), tx, rx, np.arange(100), target, 2.4e9) is None      # all fitted: on the fit links


def test_materials_at_the_edge_of_their_range_are_named():
    from rfir_stages.rf_fit.physical_stage import bound_warnings

    rows = [{"material": "wall", "eps_r": 24.9, "thickness_m": 0.2}, {"material": "desk", "eps_r": 3.0,
            "thickness_m": 0.03}, {"material": "slab", "eps_r": 4.0, "thickness_m": 0.995}]
    got = bound_warnings(rows)
    assert len(got) == 2 and got[0].startswith("wall:") and got[1].startswith("slab:")


def test_re_materialing_the_partition_changes_what_crosses_it(fitted, tmp_path):
    from rfir_stages.model.room import RoomPredictor

    from .helpers import crosses_partition, links

    r = CliRunner().invoke(app, ["edit", str(fitted / "rf.h5"), "-o", str(tmp_path / "metal.h5"),
                                 "--select", "label:partition", "--op", "material:metal"])
    assert r.exit_code == 0, r.output
    edited = read_artifact(tmp_path / "metal.h5", "rf")
    assert load_physical(edited).names[-1] == "metal"
    assert edited["material/gamma_normal_abs"][-1, 0] > 0.99
    tx, rx, tx_id, rx_id = links()
    t, x = tx[tx_id], rx[rx_id]
    before = RoomPredictor(read_artifact(fitted / "rf.h5", "rf")).path_gain_db(t, x)
    after = RoomPredictor(edited).path_gain_db(t, x)
    cross = crosses_partition(t, x)
    assert cross.sum() > 10 and (~cross).sum() > 10
    assert np.mean(after[cross] - before[cross]) < -10.0          # a metal partition blocks the direct path
    assert np.mean(np.abs(after[~cross] - before[~cross])) < 3.0   # links on one side keep their level



def test_training_antennas_inside_the_geometry_are_left_out_and_named(tmp_path):
    """A receiver standing in the partition: its training links are left out with a warning that names
    the position; the fit goes on with the rest. A file whose every antenna is inside is refused."""
    import h5py

    from .helpers import PART_X

    write_scene(tmp_path / "scene.h5", spacing_m=0.3)
    write_measurements(tmp_path / "meas.h5")
    with h5py.File(tmp_path / "meas.h5", "r+") as f:
        rx = f["rx_pos"][:]
        rx_id = f["rx_id"][:]
        rx[rx_id == 0] = (PART_X, 0.9, 1.0)                         # in the partition's plane, off its doorway
        f["rx_pos"][:] = rx
        n_left_out = int(((rx_id == 0) & (f["split"][:] == 0)).sum())
        n_train = int((f["split"][:] == 0).sum())
    fast = ["--set", "rf_fit.physical.iterations=5", "--set", "rf_fit.physical.start_iterations=2"]
    r = CliRunner().invoke(app, [*fast, "rf-fit", str(tmp_path / "scene.h5"), str(tmp_path / "meas.h5"),
                                 "-o", str(tmp_path / "rf.h5")])
    assert r.exit_code == 0, r.output
    out = " ".join(r.output.split())
    assert (f"1 antenna position(s) lie inside the geometry (e.g. [{PART_X}, 0.9, 1.0] m" in out
            and f"their {n_left_out} of {n_train} training links are left out" in out), out
    rf = read_artifact(tmp_path / "rf.h5", "rf")
    assert len(rf.free["training"]["train_rows"]) == n_train - n_left_out

    with h5py.File(tmp_path / "meas.h5", "r+") as f:
        f["rx_pos"][:] = np.tile([PART_X, 0.9, 1.0], (len(rx), 1))
    r = CliRunner().invoke(app, [*fast, "rf-fit", str(tmp_path / "scene.h5"), str(tmp_path / "meas.h5"),
                                 "-o", str(tmp_path / "rf2.h5")])
    assert r.exit_code == 2 and "inside the geometry" in r.output and not (tmp_path / "rf2.h5").exists()
