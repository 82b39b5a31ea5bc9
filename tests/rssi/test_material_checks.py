"""Fitted materials implausible for their surface (rfir_stages.model.material_checks): a floor fitted as a metal,
a wall at S 1 or 9 mm thick is flagged, its tabulated alternatives scored on links, and the scores equal a direct
evaluation of each alternative; a plausible fit is not flagged."""
import numpy as np
import pytest
import torch

from rfir_core.physics.materials import METAL_SIGMA_S_PER_M, itu_law
from rfir_stages.model.fit_physical import training_predictor
from rfir_stages.model.material_checks import (CONDUCTOR_SIGMA_S_PER_M, MIN_WALL_THICKNESS_M, S_TOP,
                                               check_materials, flag_reasons, surface_class)
from rfir_stages.model.physical import MaterialParams
from rfir_stages.model.tabulated import TYPICAL_THICKNESS_M
from rfir_stages.rf_fit.room_stage import material_rows

from .helpers import links, reference_gain_db, room_geometry

F = 2.4e9


@pytest.fixture(scope="module")
def room_links():
    room, _, names = room_geometry(0.3)
    tx, rx, ti, ri = links(n_tx=(2, 1), n_rx=(4, 3))
    t, r = tx[ti], rx[ri]
    # the closed form's floor reflects with -0.4, a lossy dielectric's coefficient; its walls are not there
    target = reference_gain_db(t, r, F)[:, None]
    return room.links(t, r, np.full(len(t), F)), target, names


def _plausible(num: int) -> MaterialParams:
    """Every material a 10 cm lossy dielectric slab (eps_r 4, sigma 0.02 S/m at 1 GHz), S 0.1."""
    return MaterialParams(num, eps_r=4.0, sigma_1ghz=0.02, thickness_m=0.1, scattering=0.1)


def _rows(p: MaterialParams, names):
    with torch.no_grad():
        return material_rows(p.values(), names, F)


def _direct_mae(lk, target, p: MaterialParams) -> float:
    """MAE [dB] of the links' prediction with p, the system gain refitted as the median residual (by hand)."""
    with torch.no_grad():
        pred = training_predictor(lk, torch.as_tensor(target))(p).numpy()[:, 0]
    res = target[:, 0] - pred
    return float(np.mean(np.abs(res - np.median(res))))


def test_surface_classes_come_from_the_names():
    assert [surface_class(n) for n in ("floor", "ceiling", "wall_a", "partition", "floorboard", "table_00",
                                       "ceiling_board", "Floor_2", "floor_concrete", "concrete", "glass", "metal",
                                       "metal_cabinet")] == \
        ["floor", "ceiling", "wall", "wall", "floor", None, "ceiling", "floor", "floor", "wall", "wall", None, None]


def test_a_floor_plan_wall_named_by_its_material_is_checked_against_that_material_first():
    from rfir_stages.model.material_checks import alternatives

    row = {"material": "brick", "sigma_s_per_m": 0.05, "gamma_normal_abs": 0.3, "scattering": 0.2,
           "thickness_m": 0.009}
    assert flag_reasons(row) == ["0.9 cm thick"]
    assert flag_reasons(dict(row, material="glass")) == []              # a pane is as thin as that
    assert [a[0] for a in alternatives("wall", "0.9 cm thick", F, 1.0, "brick")] == \
        ["brick 15 cm", "concrete 20 cm", "plasterboard 1.25 cm"]


def test_a_plausible_fit_is_not_flagged(room_links):
    lk, target, names = room_links
    p = _plausible(len(names))
    assert all(flag_reasons(r) == [] for r in _rows(p, names))
    pred = training_predictor(lk, torch.as_tensor(target))
    assert check_materials(pred, p, target, _rows(p, names), F, held_out=True) == []


def test_each_threshold_flags_its_surface_and_not_an_object_or_a_named_metal(room_links):
    _, _, names = room_links
    p = _plausible(len(names))
    floor, wall, part, table = (names.index(n) for n in ("floor", "wall_a", "partition", "table_00"))
    p.set_values(floor, sigma_1ghz=METAL_SIGMA_S_PER_M)
    p.set_values(table, sigma_1ghz=METAL_SIGMA_S_PER_M)             # an object: no surface class
    p.set_values(wall, thickness_m=0.009)
    rows = _rows(p, names)
    assert rows[floor]["sigma_s_per_m"] > CONDUCTOR_SIGMA_S_PER_M and "metal-like" in flag_reasons(rows[floor])[0]
    assert rows[wall]["thickness_m"] < MIN_WALL_THICKNESS_M and flag_reasons(rows[wall]) == ["0.9 cm thick"]
    assert flag_reasons(rows[table]) == [] and flag_reasons(rows[part]) == []
    metal_wall = dict(rows[floor], material="metal_wall")           # labelled metal: a conductor is its value
    assert flag_reasons(metal_wall) == []
    top = dict(rows[part], scattering=S_TOP + 0.01)
    assert flag_reasons(top) == [f"scattering S {S_TOP + 0.01:.2f} (top of its range)"]
    assert flag_reasons(dict(rows[part], thickness_m=0.001), thickness_known=False) == []   # half-space fit


def test_a_metal_floor_is_scored_against_its_alternatives_and_the_scores_are_direct_evaluations(room_links):
    lk, target, names = room_links
    floor = names.index("floor")
    p = _plausible(len(names))
    p.set_values(floor, eps_r=1.0, sigma_1ghz=METAL_SIGMA_S_PER_M, thickness_m=0.002)
    fitted_mae = _direct_mae(lk, target, p)
    pred = training_predictor(lk, torch.as_tensor(target))
    keep = {k: v.clone() for k, v in p.state_dict().items()}
    on_fitted = check_materials(pred, p, target, _rows(p, names), F, held_out=False)
    # on the links the values were fitted to the alternatives are named and nothing is taken
    assert [f.name for f in on_fitted] == ["floor"] and on_fitted[0].taken == ""
    assert all(torch.equal(v, keep[k]) for k, v in p.state_dict().items())
    flags = check_materials(pred, p, target, _rows(p, names), F, held_out=True)
    assert [f.name for f in flags] == ["floor"]
    f = flags[0]
    assert list(f.maes_db) == ["fitted", "concrete 20 cm", "wood 3 cm"]      # floorboard is tabulated above 2.4 GHz
    assert f.maes_db["fitted"] == pytest.approx(fitted_mae, rel=1e-12)
    for label, key in (("concrete 20 cm", "concrete"), ("wood 3 cm", "wood")):
        q = _plausible(len(names))
        eps, sig_f = itu_law(key, F)
        q.set_values(floor, eps_r=eps, sigma_1ghz=sig_f / (F / 1e9), thickness_m=TYPICAL_THICKNESS_M[key])  # d = 1
        assert f.maes_db[label] == pytest.approx(_direct_mae(lk, target, q), rel=1e-9)
    # the closed form's floor is a dielectric: an alternative does better than the metal, and is taken
    best = min(("concrete 20 cm", "wood 3 cm"), key=f.maes_db.get)
    assert f.maes_db[best] < f.maes_db["fitted"] and f.taken == best and f.taken_key == best.split()[0]
    assert on_fitted[0].maes_db == f.maes_db
    assert _rows(p, names)[floor]["sigma_s_per_m"] < 1.0 and flag_reasons(_rows(p, names)[floor]) == []
    line = f.words("the fitted links")
    assert line.startswith("floor: fitted metal-like (sigma ") and f"{best}: {f.maes_db[best]:.2f} dB" in line


def test_an_alternative_worse_than_the_fitted_value_is_not_taken(room_links):
    lk, target, names = room_links
    wall = names.index("wall_a")
    p = _plausible(len(names))
    p.set_values(wall, thickness_m=0.009)
    pred = training_predictor(lk, torch.as_tensor(target))
    with torch.no_grad():
        exact = pred(p).numpy()                # the links measured as this state predicts them: it fits exactly
    keep = {k: v.clone() for k, v in p.state_dict().items()}
    flags = check_materials(pred, p, exact, _rows(p, names), F, held_out=True)
    assert [f.name for f in flags] == ["wall_a"] and flags[0].maes_db["fitted"] == pytest.approx(0.0, abs=1e-9)
    assert all(v > 0 for k, v in flags[0].maes_db.items() if k != "fitted") and flags[0].taken == ""
    assert all(torch.equal(v, keep[k]) for k, v in p.state_dict().items())     # the fit stays what it was


def test_rf_fit_names_the_flags_with_their_alternatives_in_its_output_the_artifact_and_info(tmp_path):
    """The reduced room's closed form has no walls but the partition: the fit thins the walls it cannot see,
    and rf-fit names each thin wall with its alternatives' MAEs (printed, stored, shown by rfir info)."""
    import re

    from typer.testing import CliRunner

    from rfir_cli.main import app
    from rfir_core.artifacts import read_artifact

    from .helpers import write_measurements, write_scene

    write_scene(tmp_path / "scene.h5", spacing_m=0.3)
    write_measurements(tmp_path / "meas.h5")
    fast = ["--set", "rf_fit.physical.iterations=30", "--set", "rf_fit.physical.start_iterations=8",
            "--set", "rf_fit.room.reflection_ranges=false", "--set", "rf_fit.room.map_visibility=false"]
    r = CliRunner().invoke(app, [*fast, "rf-fit", str(tmp_path / "scene.h5"), str(tmp_path / "meas.h5"),
                                 "-o", str(tmp_path / "rf.h5")], terminal_width=400)
    assert r.exit_code == 0, r.output
    rf = read_artifact(tmp_path / "rf.h5", "rf")
    attrs = rf.free["model@attrs"]
    names = [str(n) for n in attrs["material_names"]]
    checks = [str(c) for c in attrs["material_check"]]
    thick = np.asarray(rf["material/thickness_m"])
    for name, line, th in zip(names, checks, thick):
        # every wall the fit left under MIN_WALL_THICKNESS_M is named (one replaced is named too); the table never
        should = surface_class(name) == "wall" and th < MIN_WALL_THICKNESS_M
        assert bool(line) >= should and (surface_class(name) is not None or not line), (name, line, th)
        if line:
            assert line.startswith(f"{name}: fitted ") and "MAE on the fitted links" in line
            assert line.count(" dB") >= 3                                         # the fitted value + alternatives
            assert line in " ".join(r.output.split())                             # printed at the end
    assert any(checks)                                                            # the thin walls of this room
    info = CliRunner().invoke(app, ["info", str(tmp_path / "rf.h5")], terminal_width=400)
    assert info.exit_code == 0 and sum("implausible for its surface" in s for s in info.output.splitlines()) \
        == sum(map(bool, checks))
    assert re.search(r"\[fitted .*implausible for its surface", r.output)


def test_on_links_the_fit_did_not_use_an_alternative_no_worse_replaces_the_fitted_value(tmp_path):
    """rf_fit.room.fit_links below the training links: the check scores on the links the fit left out, and a
    material replaced there is stored with the tabulated values of the alternative taken (and its key)."""
    import re

    from typer.testing import CliRunner

    from rfir_cli.main import app
    from rfir_core.artifacts import read_artifact
    from rfir_stages.model.tabulated import tabulated_values

    from .helpers import write_measurements, write_scene

    write_scene(tmp_path / "scene.h5", spacing_m=0.3)
    write_measurements(tmp_path / "meas.h5")
    fast = ["--set", "rf_fit.physical.iterations=30", "--set", "rf_fit.physical.start_iterations=8",
            "--set", "rf_fit.room.reflection_ranges=false", "--set", "rf_fit.room.map_visibility=false",
            "--set", "rf_fit.room.fit_links=50"]
    r = CliRunner().invoke(app, [*fast, "rf-fit", str(tmp_path / "scene.h5"), str(tmp_path / "meas.h5"),
                                 "-o", str(tmp_path / "rf.h5")], terminal_width=400)
    assert r.exit_code == 0, r.output
    rf = read_artifact(tmp_path / "rf.h5", "rf")
    attrs = rf.free["model@attrs"]
    names = [str(n) for n in attrs["material_names"]]
    lines = [(i, str(c)) for i, c in enumerate(attrs["material_check"]) if str(c)]
    assert lines and all("MAE on 46 training links the fit did not use" in c for _, c in lines)
    assert any("taken: " in c for _, c in lines)          # this room's closed form has no walls: a thin one is taken
    for i, line in lines:
        taken = re.search(r"taken: (\w+) ([\d.]+) cm", line)
        if taken is None:
            continue
        key, th_cm = taken.group(1), float(taken.group(2))
        maes = dict(re.findall(r"; ([\w ]+? [\d.]+ cm): ([\d.]+) dB", line))
        fitted = float(re.search(r"did not use ([\d.]+) dB", line).group(1))
        assert float(maes[f"{key} {taken.group(2)} cm"]) <= fitted                  # no worse on those links
        eps, sig = tabulated_values(key, 2.4e9, float(attrs.get("sigma_exponent", 1.0)))
        assert rf["material/eps_r"][i] == pytest.approx(eps, rel=1e-9)
        assert rf["material/sigma_1ghz_s_per_m"][i] == pytest.approx(sig, rel=1e-9)
        assert rf["material/thickness_m"][i] == pytest.approx(th_cm / 100, rel=1e-9)
        assert str(attrs["material_tabulated"][i]) == key, names[i]
