"""The room model's |Gamma(0)| ranges (rf_fit.room.reflection_ranges): the per-material split that makes them
cheap gives the ranges of the full evaluation, and rfir info names a material the links do not determine."""
import re

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from rfir_cli.main import app
from rfir_stages.geom import gaussians_from_mesh, write_scene_artifact
from rfir_stages.model.fit_physical import _material_predictor, training_predictor
from rfir_stages.model.identifiability import NOT_DETERMINED, normal_reflection_ranges
from rfir_stages.model.physical import MaterialParams
from rfir_stages.model.residual import SE_MARGIN
from rfir_stages.simulate.scenes import _merge, wall

from .helpers import links, reference_gain_db, room_geometry, room_mesh, write_measurements

F = 2.4e9


@pytest.fixture(scope="module")
def room_links():
    room, _, names = room_geometry(0.3)
    tx, rx, ti, ri = links(n_tx=(2, 1), n_rx=(4, 3))
    t, r = tx[ti], rx[ri]
    return room.links(t, r, np.full(len(t), F)), reference_gain_db(t, r, F)[:, None], names


def _params(num: int) -> MaterialParams:
    p = MaterialParams(num, eps_r=4.0, sigma_1ghz=0.02, thickness_m=0.1, shared_scattering=True)
    p.set_values(6, eps_r=3.0, sigma_1ghz=0.05, thickness_m=0.2)       # the partition: a lossy wall
    return p


def test_the_parts_with_and_without_a_material_sum_to_the_links_components(room_links):
    lk, _, names = room_links
    with torch.no_grad():
        mats = _params(len(names)).values()
        field, diff = lk.components(mats)
        for i in range(len(names)):
            rows, without, with_i = lk.material_split(i)
            f0, d0 = without.components(mats)
            f1, d1 = with_i.components(mats)
            assert torch.allclose(f0 + f1, field[rows], rtol=1e-10, atol=0) and torch.allclose(d0 + d1, diff[rows])
            others = np.setdiff1d(np.arange(lk.num_links), rows.numpy())
            assert len(with_i.paths.link) > 0 and len(others) == 0   # every material of this room reaches every link
    assert (lk.material_split(7)[2].paths.num < lk.paths.num / 2)    # the table: a few of the paths


@pytest.mark.parametrize("scattering", [None, 0.0])
def test_a_material_part_predicts_the_links_power_as_that_material_changes(room_links, scattering):
    lk, _, names = room_links
    p = _params(len(names))
    with torch.no_grad():
        for i in range(len(names)):
            part = lk.material_part(i, p.values())
            for eps, sig, th in ((1.5, 1e-3, 0.003), (25.0, 1e6, 0.2), (7.0, 0.05, 0.05)):
                q = _params(len(names))
                q.shared_scattering = False
                q.set_values(i, eps_r=eps, sigma_1ghz=sig, thickness_m=th, scattering=scattering)
                want = lk.power(q.values())[part.rows, 0]
                assert torch.allclose(part.power(q.values()), want, rtol=1e-10, atol=0)


def test_the_fast_ranges_are_those_of_the_full_prediction(room_links):
    lk, target, names = room_links
    p = _params(len(names))
    fast = normal_reflection_ranges(training_predictor(lk, target), p, target, F, margin=SE_MARGIN,
                                    local=_material_predictor(lk, target, None))
    slow = normal_reflection_ranges(training_predictor(lk, target), p, target, F, margin=SE_MARGIN)
    assert np.allclose(fast, slow, atol=1e-9)
    assert (slow[:, 1] - slow[:, 0]).max() > 0.05                 # some range is wider than the fitted point


def _scene_with_an_unseen_plate(path):
    """The reduced room and a 0.2 m plate outside it, 0.3 m behind wall_a by the floor and facing away: no path
    of the links reflects off it or crosses it (one inside the room is crossed by some third-order path)."""
    v, f, lab, names = room_mesh()
    pv, pf = wall((-0.3, 0.05, 0.05), (0, 1, 0), (-1, 0, 0), 0.2, 0.2)
    v2, f2 = _merge([(v, f), (pv, pf)])
    lab = np.concatenate([lab, np.full(len(pf), len(names))])
    fields = gaussians_from_mesh(v2, f2, 0.3, labels=lab)
    return write_scene_artifact(path, fields, label_names=[*names, "plate"], spacing_m=0.3)


def test_info_shows_the_ranges_and_names_a_material_no_link_sees(tmp_path):
    _scene_with_an_unseen_plate(tmp_path / "scene.h5")
    write_measurements(tmp_path / "meas.h5", n_tx=(2, 1), n_rx=(4, 3))
    fast = ["--set", "rf_fit.physical.iterations=5", "--set", "rf_fit.physical.start_iterations=2",
            "--set", "rf_fit.room.diffuse=false", "--set", "rf_fit.room.tabulated_materials=false"]
    r = CliRunner().invoke(app, [*fast, "rf-fit", str(tmp_path / "scene.h5"), str(tmp_path / "meas.h5"),
                                 "-o", str(tmp_path / "rf.h5")])     # the ranges on by default for rooms
    assert r.exit_code == 0, r.output
    out = " ".join(r.output.split())
    assert "no training path reflects off or crosses plate" in out
    assert re.search(r"plate .*\(links allow 0\.\d\d-\d\.\d\d, " + NOT_DETERMINED + r"\)", out)
    info = CliRunner().invoke(app, ["info", str(tmp_path / "rf.h5")], terminal_width=240)
    assert info.exit_code == 0 and "|Gamma(0)| range 2.4 GHz" in info.output
    row = next(line for line in info.output.splitlines() if line.startswith("plate"))
    assert re.search(r"0\.\d\d-\d\.\d\d " + NOT_DETERMINED, row)
