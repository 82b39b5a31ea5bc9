"""Material laws, Fresnel and slab coefficients against closed forms (docs/physics.md section 8)."""
import math

import numpy as np
import pytest
import torch

from rfir_core.physics import materials as m
from rfir_stages.po import facet_materials as po_materials


def test_itu_law_concrete_at_2_4_ghz():
    eps_r, sigma = m.itu_law("itu_concrete", 2.4e9)
    assert eps_r == pytest.approx(5.24)
    assert sigma == pytest.approx(0.0462 * 2.4**0.7822)
    assert sigma == pytest.approx(0.092, abs=1e-3)       # the value Sionna RT reports
    with pytest.raises(ValueError, match="unknown material"):
        m.itu_law("unobtainium", 2.4e9)


def test_perfect_conductor_and_metal():
    r_te, r_tm = m.fresnel(complex(1.0, -math.inf), torch.linspace(0, 1, 5))
    assert torch.allclose(r_te, torch.full((5,), -1 + 0j, dtype=torch.complex128))
    assert torch.allclose(r_tm, torch.full((5,), 1 + 0j, dtype=torch.complex128))
    eta = m.permittivity(*m.itu_law("metal", 2.4e9), 2.4e9)
    assert abs(m.normal_incidence_reflection(eta)) > 0.999


def test_lossless_dielectric_normal_incidence_and_brewster():
    eps = 4.0
    r_te, r_tm = m.fresnel(eps, 1.0)
    assert r_te.item() == pytest.approx((1 - 2) / (1 + 2))     # (1 - sqrt(eps)) / (1 + sqrt(eps))
    assert r_tm.item() == pytest.approx(-r_te.item())           # the PO convention: R_TM = -R_TE at normal incidence
    brewster = math.atan(math.sqrt(eps))
    assert abs(m.fresnel(eps, math.cos(brewster))[1].item()) < 1e-12
    assert abs(m.fresnel(eps, math.cos(brewster))[0].item()) > 0.3


@pytest.mark.parametrize("cos_theta", [1.0, 0.7, 0.3])
def test_lossless_slab_conserves_energy(cos_theta):
    k0 = 2 * math.pi * 2.4e9 / m.C0
    for d in (0.003, 0.02, 0.11):
        r_te, r_tm = m.fresnel(2.7, cos_theta, k0, d)
        t_te, t_tm = m.slab_transmission(2.7, cos_theta, k0, d)
        assert (abs(r_te) ** 2 + abs(t_te) ** 2).item() == pytest.approx(1.0, abs=1e-12)
        assert (abs(r_tm) ** 2 + abs(t_tm) ** 2).item() == pytest.approx(1.0, abs=1e-12)


def test_half_wave_slab_is_transparent_and_thick_lossy_slab_is_a_half_space():
    eps, f = 4.0, 2.4e9
    k0 = 2 * math.pi * f / m.C0
    d = math.pi / (k0 * math.sqrt(eps))                  # q = pi at normal incidence
    assert abs(m.fresnel(eps, 1.0, k0, d)[0].item()) < 1e-12
    assert abs(abs(m.slab_transmission(eps, 1.0, k0, d)[0].item()) - 1.0) < 1e-12
    eta = m.permittivity(5.24, 5.0, f)                   # very lossy: the back face is never seen
    assert torch.allclose(m.fresnel(eta, 0.8, k0, 0.5)[0], m.fresnel(eta, 0.8)[0], atol=1e-9)
    assert abs(m.slab_transmission(complex(1, -math.inf), 0.5, k0, 0.01)[0].item()) == 0.0


def test_concrete_wall_transmission_loss_is_about_ten_db():
    # ITU concrete, 0.2 m, 2.4 GHz, normal incidence: a few dB per 10 cm (the figure the room issues quote)
    eta = m.permittivity(*m.itu_law("concrete", 2.4e9), 2.4e9)
    t = m.slab_transmission(eta, 1.0, 2 * math.pi * 2.4e9 / m.C0, 0.2)[0]
    loss_db = -20 * math.log10(abs(t.item()))
    assert 8.0 < loss_db < 25.0


def test_co_polar_reflection():
    r_te, r_tm = m.fresnel(3.0, 0.6)
    assert m.co_polar_reflection(r_te, r_tm, 1.0) == r_te
    assert m.co_polar_reflection(r_te, r_tm, 0.0) == -r_tm
    pec = m.fresnel(complex(1, -math.inf), 0.6)
    assert torch.allclose(m.co_polar_reflection(*pec, torch.tensor([0.0, 0.3, 1.0])),
                          torch.full((3,), -1 + 0j, dtype=torch.complex128))


def test_gradients_are_finite_for_every_material():
    eps = torch.tensor([1.0, 2.7, 6.0], dtype=torch.float64, requires_grad=True)
    log_sigma = torch.tensor([-3.0, 0.0, 7.0], dtype=torch.float64, requires_grad=True)
    th = torch.tensor([0.005, 0.05, 0.5], dtype=torch.float64, requires_grad=True)
    eta = m.permittivity(eps, 10**log_sigma, 2.4e9)
    r = m.fresnel(eta, torch.tensor([1.0, 0.5, 0.1], dtype=torch.float64), 50.0, th)[0]
    r.abs().sum().backward()
    for p in (eps, log_sigma, th):
        assert torch.isfinite(p.grad).all()


def test_po_solver_uses_the_same_definition():
    eta = po_materials.relative_permittivity("glass", np.array([2.4e9, 5.8e9]))
    np.testing.assert_allclose(eta, m.permittivity(*m.itu_law("glass", np.array([2.4e9, 5.8e9])),
                                                  np.array([2.4e9, 5.8e9])).numpy())
    r_np = po_materials.fresnel(eta, 0.5, np.array([2.4e9, 5.8e9]), 0.01)[0]
    k0 = 2 * math.pi * np.array([2.4e9, 5.8e9]) / m.C0
    np.testing.assert_allclose(r_np, m.fresnel(eta, 0.5, k0, 0.01)[0].numpy(), rtol=1e-6)
