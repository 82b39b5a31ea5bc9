"""The surfels' sampling check: coarse cells against the wavelength are named, with a spacing that cures it."""
import re

import pytest

from rfir_stages.model.sampling import cell_size_m, coarse_surfels_warning
from rfir_stages.model.surfels import surfel_areas

from .helpers import plate_mesh, surfels


def _cells(spacing_m):
    v, f = plate_mesh((0.0, 0.0, 0.0), (1, 0, 0), (0, 1, 0), 0.3, 0.2)
    geom, _ = surfels(v, f, spacing_m)
    return cell_size_m(geom.log_scales, geom.rotations, geom.normals,
                       surfel_areas(geom.means, geom.log_scales, geom.rotations, geom.normals))


def test_cells_shrink_with_the_spacing_and_stay_below_it():
    coarse, fine = _cells(0.03), _cells(0.015)
    assert 0.3 * 0.03 < coarse <= 0.03 and 0.3 * 0.015 < fine <= 0.015
    assert fine == pytest.approx(coarse / 2, rel=0.2)


def test_coarse_cells_are_named_at_the_frequency_they_fail_and_the_advice_cures_it():
    cell = _cells(0.03)
    assert coarse_surfels_warning(cell, [2.4e9]) is None
    msg = coarse_surfels_warning(cell, [2.4e9, 5.8e9])
    assert msg is not None and "5.8 GHz" in msg
    spacing = float(re.search(r"--spacing ([0-9.]+)", msg).group(1))
    assert spacing < 0.03
    assert coarse_surfels_warning(_cells(spacing), [5.8e9]) is None
    assert coarse_surfels_warning(0.0, [5.8e9]) is None and coarse_surfels_warning(cell, []) is None
