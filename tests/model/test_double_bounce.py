"""The model's double bounce (docs/physics.md section 8.7) against the dihedral's closed form and the PO solver."""
import math

import numpy as np
import pytest
import torch

from rfir_core.physics.closed_forms import C0
from rfir_stages.model.physical import MaterialParams, PairSettings, build_pairs, scattered_power
from rfir_stages.model.second_order import polarisation_chain
from rfir_stages.model.occlusion import make_provider

from .helpers import ISO, monostatic, plate_mesh, rcs_dbsm, surfels

PEC_LIKE = dict(eps_r=1.0, sigma_1ghz=1e7, scattering=1e-9, thickness_m=None)
A_M, B_M = 0.2, 0.25        # face size from the fold, size along the fold


def _dihedral(spacing_m):
    """A 90-degree dihedral, fold on the z axis, faces along +x and +y (bisector at aspect 45 degrees)."""
    v1, f1 = plate_mesh((A_M / 2, 0, 0), (1, 0, 0), (0, 0, 1), A_M, B_M)
    v2, f2 = plate_mesh((0, A_M / 2, 0), (0, 1, 0), (0, 0, 1), A_M, B_M)
    verts, faces = np.concatenate([v1, v2]), np.concatenate([f1, f2 + 4])
    return surfels(verts, faces, spacing_m)[0], verts, faces


def _power(geom, links, settings):
    pairs = build_pairs(geom, links, ISO, ISO, make_provider("auto", geom), settings)
    mats = MaterialParams(1, **PEC_LIKE).values()
    return scattered_power(pairs, torch.zeros(geom.num, dtype=torch.int64), mats).detach().numpy()[:, 0]


@pytest.mark.parametrize("spacing_m", [0.02, 0.04])
@pytest.mark.parametrize("freq_hz", [2.4e9, 5.8e9])
def test_dihedral_flash_whatever_the_spacing(spacing_m, freq_hz):
    """At its bisector (far field) a dihedral returns 8 pi a^2 b^2 / lambda^2 within 1 dB at either
    surfel spacing; the first order alone is more than 10 dB short."""
    geom, _, _ = _dihedral(spacing_m)
    _, links = monostatic([45.0], 200.0, freq_hz)
    closed = 10 * np.log10(8 * math.pi * A_M**2 * B_M**2 / (C0 / freq_hz) ** 2)
    both = rcs_dbsm(_power(geom, links, PairSettings()), 200.0, freq_hz)[0]
    first = rcs_dbsm(_power(geom, links, PairSettings(second_order=False)), 200.0, freq_hz)[0]
    assert abs(both - closed) < 1.0
    assert first < closed - 10.0


@pytest.mark.parametrize("polarisation", ["V", "H"])
@pytest.mark.parametrize("freq_hz", [2.4e9, 5.8e9])
def test_dihedral_curve_over_45_degrees_against_po(polarisation, freq_hz):
    """Monostatic at 3 m over the bisector +-45 degrees, where the single and the double bounces
    interfere: the model against the PO solver (ray tubes of 2 mm, converged here) on the same mesh.
    V: E along the fold (TE at both faces); H: E across it (TM at both), whose double bounce has the
    opposite sign (a per-bounce co-polarised coefficient gives it the wrong sign: errors of 3 dB)."""
    from rfir_stages.po import po_scattered_field

    geom, verts, faces = _dihedral(0.02)
    pos, links = monostatic(np.arange(0.0, 91.0, 6.0), 3.0, freq_hz)
    ours = rcs_dbsm(_power(geom, links, PairSettings(polarisation=polarisation)), 3.0, freq_hz)
    s = po_scattered_field(verts, faces, "pec", pos, pos, [freq_hz], near_field=True, second_order=True,
                           sbr_spacing_m=0.002, polarization=polarisation)
    err = ours - 20 * np.log10(np.abs(s[:, 0]))
    assert np.abs(err).mean() < 0.4 and np.abs(err).max() < 1.0


def test_polarisation_chain_of_a_dihedral():
    """A perfect conductor's dihedral (R_TE = -1, R_TM = +1) in its plane: E along the fold returns
    R_TE^2 = +1, E across it -R_TM^2 = -1 (a plate returns -1 for both), at every aspect."""
    for aspect in (20.0, 45.0, 70.0):
        phi = math.radians(aspect)
        d = torch.tensor([[-math.cos(phi), -math.sin(phi), 0.0]], dtype=torch.float64)   # Tx -> dihedral
        n_a = torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64)                        # face along +x
        n_b = torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64)                        # face along +y
        d2 = d - 2.0 * (d * n_a).sum(-1, keepdim=True) * n_a
        v = polarisation_chain(d, n_a, d2, n_b, -d, "V")[0].numpy()
        h = polarisation_chain(d, n_a, d2, n_b, -d, "H")[0].numpy()
        np.testing.assert_allclose(v @ np.array([1.0, -1.0, -1.0, 1.0]), 1.0, atol=1e-12)   # R_TE, R_TM = -1, +1
        np.testing.assert_allclose(h @ np.array([1.0, -1.0, -1.0, 1.0]), -1.0, atol=1e-12)
        np.testing.assert_allclose(v, [1.0, 0.0, 0.0, 0.0], atol=1e-12)
        np.testing.assert_allclose(h, [0.0, 0.0, 0.0, -1.0], atol=1e-12)

