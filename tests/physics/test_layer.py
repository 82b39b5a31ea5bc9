"""The physics layer (rfir_core.physics) against closed forms: Fresnel at normal incidence and at Brewster's angle, a
slab of zero thickness, energy conservation of a lossless slab, the polarisation bases, the dispersion law, the
specular share, the angle tables and the segment hits that decide a crossing."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from rfir_core.physics.angle_nodes import AngleNodes
from rfir_core.physics.crossings import LEG_MARGIN_M, segment_hits
from rfir_core.physics.materials import (EPS0, ITU_MATERIALS, METAL_SIGMA_S_PER_M, fresnel, itu_law, law_permittivity,
                                         permittivity, power_law, slab_transmission, specular_share)
from rfir_core.physics.polarisation import antenna_polarisation, mirror_direction, reflection_basis, te_share

RNG = np.random.default_rng(7)


def _units(n: int) -> np.ndarray:
    v = RNG.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.mark.parametrize("eta", [4.0, 2.25 - 0.3j, 6.31 - 0.05j])
def test_fresnel_at_normal_incidence_is_the_impedance_step(eta):
    r_te, r_tm = fresnel(eta, 1.0)
    expected = (1 - np.sqrt(eta)) / (1 + np.sqrt(eta))
    assert complex(r_te) == pytest.approx(expected, abs=1e-12)
    assert complex(r_tm) == pytest.approx(-expected, abs=1e-12)    # R_TM = -R_TE there (the TM reference)


def test_tm_reflection_vanishes_at_brewsters_angle_only():
    eta = 4.0
    brewster = math.atan(math.sqrt(eta))
    r_te, r_tm = fresnel(eta, math.cos(brewster))
    assert abs(complex(r_tm)) < 1e-12 and abs(complex(r_te)) > 0.5
    off = fresnel(eta, math.cos(brewster + 0.05))[1]
    assert abs(complex(off)) > 1e-2


def test_perfect_conductor_reflects_minus_one_and_plus_one():
    r_te, r_tm = fresnel(complex(1.0, -math.inf), torch.linspace(0, 1, 5, dtype=torch.float64))
    assert torch.allclose(r_te, torch.full_like(r_te, -1)) and torch.allclose(r_tm, torch.full_like(r_tm, 1))


def test_slab_of_zero_thickness_is_transparent():
    eta, cos = 5.24 - 0.4j, torch.linspace(0.05, 1.0, 9, dtype=torch.float64)
    k0 = 2 * math.pi * 2.4e9 / 299_792_458.0
    t_te, t_tm = slab_transmission(eta, cos, k0, 0.0)
    assert torch.allclose(t_te, torch.ones_like(t_te)) and torch.allclose(t_tm, torch.ones_like(t_tm))
    r_te, r_tm = fresnel(eta, cos, k0, 1e-12)
    assert float(r_te.abs().max()) < 1e-8 and float(r_tm.abs().max()) < 1e-8   # R ~ k0 d: first order in d


@pytest.mark.parametrize("thickness_m", [0.003, 0.05, 0.2])
def test_lossless_slab_conserves_energy(thickness_m):
    eta, cos = 6.31, torch.linspace(0.02, 1.0, 25, dtype=torch.float64)
    k0 = 2 * math.pi * 5.8e9 / 299_792_458.0
    r = fresnel(eta, cos, k0, thickness_m)
    t = slab_transmission(eta, cos, k0, thickness_m)
    for pol in (0, 1):
        total = r[pol].abs() ** 2 + t[pol].abs() ** 2
        assert torch.allclose(total, torch.ones_like(total), atol=1e-12)
    lossy = fresnel(eta - 1.0j, cos, k0, thickness_m)[0].abs() ** 2 + \
        slab_transmission(eta - 1.0j, cos, k0, thickness_m)[0].abs() ** 2
    assert float(lossy.max()) < 1 - 1e-3     # a lossy slab absorbs: the check can tell


def test_dispersion_law_is_the_itu_power_law():
    a, b, c, d, _, _ = ITU_MATERIALS["concrete"]
    eps, sigma = itu_law("concrete", 5.8e9)
    assert eps == pytest.approx(a * 5.8**b) and sigma == pytest.approx(c * 5.8**d)
    assert float(power_law(torch.tensor(2.0), 0.5, torch.tensor(4e9))) == pytest.approx(4.0)
    eta = law_permittivity(3.0, 0.0, 0.02, 1.5, 2e9)
    assert complex(eta) == pytest.approx(3.0 - 1j * 0.02 * 2**1.5 / (EPS0 * 2 * math.pi * 2e9))
    assert complex(eta) == pytest.approx(complex(permittivity(3.0, 0.02 * 2**1.5, 2e9)))
    assert ITU_MATERIALS["metal"][2] == METAL_SIGMA_S_PER_M
    # a metal's reflection is a conductor's at every frequency of the table's range
    r = fresnel(law_permittivity(1.0, 0.0, METAL_SIGMA_S_PER_M, 0.0, torch.tensor([1e9, 100e9])), 1.0)[0]
    assert float((r + 1).abs().max()) < 1e-2


def test_specular_share_is_the_amplitude_left_after_scattering():
    s = torch.tensor([0.0, 0.3, 0.6, 1.0, 1.0 + 1e-9], dtype=torch.float64)
    share = specular_share(s)
    assert torch.allclose(share[:4] ** 2 + s[:4] ** 2, torch.ones(4, dtype=torch.float64))
    assert float(share[-1]) == 0.0 and torch.isfinite(share).all()


@pytest.mark.parametrize("kind", ["numpy", "torch"])
def test_antenna_polarisation_is_sionnas_theta_and_phi(kind):
    theta, phi = RNG.uniform(0.1, math.pi - 0.1, 50), RNG.uniform(-math.pi, math.pi, 50)
    k = np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], 1)
    theta_hat = np.stack([np.cos(theta) * np.cos(phi), np.cos(theta) * np.sin(phi), -np.sin(theta)], 1)
    phi_hat = np.stack([-np.sin(phi), np.cos(phi), np.zeros_like(phi)], 1)
    arg = torch.as_tensor(k) if kind == "torch" else k
    v, h = (np.asarray(antenna_polarisation(arg, p)) for p in ("V", "H"))
    assert np.allclose(v, theta_hat, atol=1e-12) and np.allclose(h, phi_hat, atol=1e-12)
    # straight up and down: V is +x's part across k, H = k x V; both unit and across k
    up = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]])
    v, h = antenna_polarisation(up, "V"), antenna_polarisation(up, "H")
    assert np.allclose(v, [[1, 0, 0], [1, 0, 0]]) and np.allclose(h, np.cross(up, v))
    with pytest.raises(ValueError, match="polarisation"):
        antenna_polarisation(k, "X")


@pytest.mark.parametrize("kind", ["numpy", "torch"])
def test_reflection_basis_is_orthonormal_and_right_handed(kind):
    k, n = _units(200), _units(200)
    k[:3] = n[:3]                        # normal incidence, where the plane of incidence is undefined
    k[3:6] = -n[3:6]
    conv = torch.as_tensor if kind == "torch" else np.asarray
    e_te, e_in, e_out = (np.asarray(x) for x in reflection_basis(conv(k), conv(n)))
    k_out = mirror_direction(k, n)
    for a, b in ((e_te, e_in), (e_te, e_out), (e_te, k), (e_in, k), (e_out, k_out)):
        assert np.allclose((a * b).sum(1), 0.0, atol=1e-12)
    for a in (e_te, e_in, e_out):
        assert np.allclose(np.linalg.norm(a, axis=1), 1.0)
    assert np.allclose(np.cross(e_te, e_in), k) and np.allclose(np.cross(e_te, e_out), k_out)
    assert np.allclose((e_te * n).sum(1), 0.0, atol=1e-12)      # TE lies in the plane


def test_basis_and_fresnel_signs_give_a_mirror_for_a_perfect_conductor():
    """A perfect conductor's reflected field is the mirror image E_r = -E + 2 (E . n) n of the incident one; with
    R_TE = -1, R_TM = +1 on the TE/TM basis this holds only if the two conventions agree."""
    k, n = _units(100), _units(100)
    n = np.where((k * n).sum(1, keepdims=True) > 0, -n, n)   # the normal facing the wave
    e = np.cross(k, _units(100))
    e /= np.linalg.norm(e, axis=1, keepdims=True)               # a field across k
    e_te, e_in, e_out = reflection_basis(k, n)
    r_te, r_tm = -1.0, 1.0
    reflected = r_te * (e * e_te).sum(1, keepdims=True) * e_te + r_tm * (e * e_in).sum(1, keepdims=True) * e_out
    assert np.allclose(reflected, -e + 2 * (e * n).sum(1, keepdims=True) * n, atol=1e-12)


def test_te_share_of_vertical_and_horizontal_waves_on_a_wall_and_a_floor():
    k = np.array([[1.0, 0.0, 0.0]])
    wall = np.array([[-1.0, 0.0, 0.0]])                  # normal incidence: TE and TM alike
    assert te_share(k, wall, "V")[0] == 0.5
    k = np.array([[math.sqrt(0.5), math.sqrt(0.5), 0.0]])
    wall = np.array([[-1.0, 0.0, 0.0]])                  # a vertical wall, horizontal wave: V is TE
    assert te_share(k, wall, "V")[0] == pytest.approx(1.0) and te_share(k, wall, "H")[0] == pytest.approx(0.0)
    k = np.array([[math.sqrt(0.5), 0.0, -math.sqrt(0.5)]])
    floor = np.array([[0.0, 0.0, 1.0]])                  # the floor: H is TE, V is TM
    assert te_share(torch.as_tensor(k), torch.as_tensor(floor), "H")[0] == pytest.approx(1.0)
    assert te_share(k, floor, "V")[0] == pytest.approx(0.0, abs=1e-12)


def test_angle_nodes_interpolate_a_linear_law_exactly():
    nodes = AngleNodes(46)
    theta = torch.linspace(0, math.pi / 2, 46, dtype=torch.float64)
    assert torch.allclose(nodes.cosines(), torch.cos(theta))
    table = 3.0 * theta + 1.0                            # linear in the angle: interpolation is exact
    cos = torch.as_tensor(RNG.uniform(0, 1, 100))
    j, w = nodes.position(cos)
    assert int(j.min()) >= 0 and int(j.max()) <= 44
    assert torch.allclose((1 - w) * table[j] + w * table[j + 1], 3.0 * torch.arccos(cos) + 1.0)
    jn, wn = nodes.position(cos.numpy())
    assert np.array_equal(jn, j.numpy()) and np.allclose(wn, w.numpy())
    assert nodes.nearest(torch.tensor([1.0, 0.0], dtype=torch.float64)).tolist() == [0, 45]
    with pytest.raises(ValueError):
        AngleNodes(1)


class _Hits:
    """A provider whose rays hit Gaussians at given distances: hits [(ray, gaussian, t)], every one before t_max."""

    def __init__(self, hits):
        self.hits = hits

    def ray_hits(self, origins, directions, t_max=None):
        rows = [(q, g, t) for q, g, t in self.hits if t_max is None or t < float(t_max[q])]
        q, g, t = (torch.tensor([r[i] for r in rows], dtype=torch.float64 if i == 2 else torch.int64) for i in range(3))
        return SimpleNamespace(query=q, gaussian=g, t_m=t, response=torch.ones(len(rows), dtype=torch.float64))


def test_segment_hits_leave_out_the_surfaces_at_either_end():
    start, end = np.zeros((2, 3)), np.array([[2.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    provider = _Hits([(0, 5, 0.01), (0, 6, 1.0), (0, 7, 1.99), (1, 8, LEG_MARGIN_M + 1e-6), (1, 9, 0.5)])
    leg, gaussian, t, _ = segment_hits(provider, start, end)
    assert leg.tolist() == [0, 1, 1] and gaussian.tolist() == [6, 8, 9] and t.tolist()[0] == 1.0


def test_a_material_that_is_vacuum_reflects_nothing_and_transmits_fully_at_every_angle():
    """eta = 1 has no interface: R = 0 and |T| = 1 at every incidence, grazing included (where the formulas are 0/0)."""
    # cos(pi / 2) = 6e-17 is the angle tables' grazing node: 1 - c^2 rounds to 1 there, the faces' r to 1, and the
    # slab's formulas to 0/0
    cos_theta = torch.tensor([0.0, math.cos(math.pi / 2), 1e-6, 0.3, 1.0], dtype=torch.float64)
    vacuum = torch.tensor(1.0 + 0j, dtype=torch.complex128)
    for r in fresnel(vacuum, cos_theta) + fresnel(vacuum, cos_theta, k0=50.0, thickness_m=torch.tensor(0.1)):
        # 1 - (1 - c^2) loses digits near grazing: 1e-4, not machine precision
        assert torch.all(torch.isfinite(r)) and torch.all(r.abs() < 1e-4), r
    for t in slab_transmission(vacuum, cos_theta, 50.0, torch.tensor(0.1)):
        assert torch.all(torch.isfinite(t)), t
        np.testing.assert_allclose(t.abs().numpy(), 1.0, atol=1e-9)
