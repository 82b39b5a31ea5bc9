"""The surfel oracle (geom.from_mesh) and the antenna patterns."""
import math

import numpy as np
import pytest
import torch

from rfir_core.errors import InputFileError
from rfir_core.physics.gaussian_rf import covariance, projected_cross_section_m2, quaternion_to_matrix
from rfir_stages.geom import gaussians_from_mesh
from rfir_stages.model.antenna_patterns import AntennaPattern, from_table_file, resolve_antenna
from rfir_stages.simulate.scenes import box


def test_surfels_tile_the_mesh_with_face_normals_and_areas():
    v, f = box((-0.1, -0.2, -0.05), (0.1, 0.2, 0.05))
    fields = gaussians_from_mesh(v, f, 0.03, labels=np.arange(len(f)) // 2)
    means = fields["gaussians/means"]
    assert np.all(np.abs(means) <= [0.1 + 1e-9, 0.2 + 1e-9, 0.05 + 1e-9])
    rot = quaternion_to_matrix(torch.as_tensor(fields["gaussians/rotations"]))
    normals = torch.as_tensor(fields["gaussians/normals"])
    np.testing.assert_allclose(rot[:, :, 2], normals, atol=1e-12)               # thin axis = normal
    np.testing.assert_allclose(torch.linalg.det(rot), 1.0, atol=1e-12)
    # every normal points out of the box: along the axis where the mean touches the box
    outward = np.sign(np.einsum("gi,gi->g", means, fields["gaussians/normals"]))
    assert np.all(outward > 0)
    cov = covariance(torch.as_tensor(fields["gaussians/log_scales"]), torch.as_tensor(fields["gaussians/rotations"]))
    area = projected_cross_section_m2(cov, normals[None])[0]
    np.testing.assert_allclose(float(area.sum()), 2 * (0.2 * 0.4 + 0.2 * 0.1 + 0.4 * 0.1), rtol=1e-9)
    assert set(np.unique(fields["gaussians/labels"])) == set(range(6))
    assert np.all(np.exp(fields["gaussians/log_scales"][:, :2]) < 0.03)


def test_antenna_patterns(tmp_path):
    d = torch.tensor([[1.0, 0, 0], [0, 1.0, 0], [-1.0, 0, 0]], dtype=torch.float64)
    axis = torch.tensor([1.0, 0, 0], dtype=torch.float64)
    np.testing.assert_allclose(AntennaPattern("dipole").gain(d, torch.tensor([0, 0, 1.0], dtype=torch.float64)), 1.5)
    horn = AntennaPattern("horn", hpbw_deg=40.0).gain(d, axis)
    assert horn[1] == 0 and horn[2] == 0 and horn[0] > 20
    path = tmp_path / "pattern.csv"
    path.write_text("theta_deg,gain_dbi\n0,10\n90,0\n180,-10\n")
    table = from_table_file(path)
    np.testing.assert_allclose(table.gain(d, axis), [10.0, 1.0, 0.1], rtol=1e-12)
    path.write_text("angle,gain\n0,1\n")
    with pytest.raises(InputFileError):
        from_table_file(path)
    auto = resolve_antenna("auto", 40.0, "", {"horn_hpbw_deg": 30.0}, "rcs")
    assert auto.kind == "horn" and auto.hpbw_deg == 30.0
    assert resolve_antenna("auto", 40.0, "", {}, "rssi").kind == "isotropic"
    assert math.isclose(AntennaPattern("horn").boresight_gain, 24.29, rel_tol=1e-3)


def test_positions_inside_a_closed_box_are_refused_and_outside_accepted():
    """check_positions against the box's own geometry: every point well inside refused, outside fine."""
    from rfir_stages.model.links import _enclosed, check_positions, geometry_from_artifact

    from .helpers import box_fields

    fields = box_fields(0.2, 0.03)
    geom = geometry_from_artifact({k: v for k, v in fields.items()})
    g = torch.Generator().manual_seed(3)
    pts = (torch.rand(400, 3, generator=g, dtype=torch.float64) * 2 - 1) * 0.35
    inside = (pts.abs() < 0.15).all(-1)
    outside = (pts.abs() > 0.25).any(-1)
    assert bool(_enclosed(geom, pts[inside]).all()) and not bool(_enclosed(geom, pts[outside]).any())
    check_positions(geom, pts[outside].numpy(), "m.h5", 0.0)
    with pytest.raises(InputFileError, match="enclosed"):
        check_positions(geom, pts[inside][:3].numpy(), "m.h5", 0.0)
