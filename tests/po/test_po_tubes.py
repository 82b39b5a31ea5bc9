"""The PO solver's double-bounce ray tubes at grazing first bounces (stages/po/multi_bounce.py)."""
import numpy as np
import pytest

import rfir_stages.po.multi_bounce as second_order
from rfir_stages.po import po_scattered_field


def _box(centre, size):
    c, h = np.asarray(centre, float), np.asarray(size, float) / 2
    v = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float) * h + c
    f = [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1], [2, 3, 7], [2, 7, 6], [0, 2, 6],
         [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    return v, np.array(f)


def _step_rcs_db(spacing_m, freq_hz=2.4e9):
    """A step of two metal bricks (a low one in front of a high one), radar at 3 m seeing the low
    brick's top at 2 degrees: its double bounce is top -> the high brick's face -> radar, over a
    strip of the top that a coarse tube (seen at 2 degrees it covers spacing / sin 2 deg) overshoots."""
    v1, f1 = _box((0.0, 0.0, 0.02), (0.08, 0.16, 0.04))
    v2, f2 = _box((-0.08, 0.0, 0.04), (0.08, 0.16, 0.08))
    verts, faces = np.concatenate([v1, v2]), np.concatenate([f1, f2 + 8])
    az, el = np.radians(np.arange(-40.0, 41.0, 4.0)), np.radians(2.0)
    pos = np.stack([3 * np.cos(el) * np.cos(az), 3 * np.cos(el) * np.sin(az), 0.04 + 3 * np.sin(el) + 0 * az], 1)
    s = po_scattered_field(verts, faces, "pec", pos, pos, [freq_hz], near_field=True, second_order=True,
                           sbr_spacing_m=spacing_m, polarization="V")
    return 20 * np.log10(np.abs(s[:, 0]))


def test_grazing_tubes_are_split_until_converged(monkeypatch):
    """Tubes of lambda / 4 (3.1 cm at 2.4 GHz) agree with 3 mm tubes within 0.3 dB MAE because the
    tubes whose footprint is long are split; without the split (REFINE_MAX = 1) they are more than
    1.5 dB off, the error the split removes. The default spacing agrees as well."""
    reference = _step_rcs_db(0.003)
    coarse = _step_rcs_db(0.03125)
    default = _step_rcs_db(None)
    monkeypatch.setattr(second_order, "REFINE_MAX", 1)
    unsplit = _step_rcs_db(0.03125)
    assert np.abs(coarse - reference).mean() < 0.3
    assert np.abs(default - reference).mean() < 0.3
    assert np.abs(unsplit - reference).mean() > 1.5


def test_auto_tube_spacing():
    """lambda_min / 20 for a small object; wider for a large one, at most MAX_TUBES tubes across it."""
    ks = 2 * np.pi * np.array([2.4e9, 5.8e9]) / 299792458.0
    small = np.array([[0.0, 0, 0], [0.3, 0.2, 0.1]])
    large = np.array([[0.0, 0, 0], [4.5, 1.8, 1.4]])
    assert second_order.auto_tube_spacing(small, ks) == pytest.approx(299792458.0 / 5.8e9 / 20)
    wide = second_order.auto_tube_spacing(large, ks)
    extent = np.linalg.norm(large[1] - large[0])
    assert wide > 299792458.0 / 5.8e9 / 20 and (extent / wide) ** 2 <= second_order.MAX_TUBES * 1.0001
