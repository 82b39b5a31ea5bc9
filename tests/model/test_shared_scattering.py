"""One scattering coefficient S for every material (MaterialParams.shared_scattering, rf_fit.room.scattering).

The fit test's links are synthetic: link m reflects off one plate at incidence angle theta_m, its power
|R_TE|^2 (1 - S^2) (the specular share) + 0.2 S^2 |R_TE|^2 (a little diffuse power), so that S trades with
|Gamma| for a dielectric. A metal plate (|Gamma| = 1) fixes S; shared, S then holds for the dielectric too."""
from __future__ import annotations

import math

import numpy as np
import torch

from rfir_stages.model.fit_physical import PhysicalFitConfig, _raw, fit_materials
from rfir_core.physics.materials import C0, fresnel
from rfir_stages.model.physical import MaterialParams
from rfir_stages.model.tabulated import tabulated_values

F = 2.4e9
K0 = 2 * math.pi * F / C0


class _Plates:
    """power(mats, gain_db) [M, 1] W of links each reflecting off plate which[m] at cos[m] (the fit's model)."""

    def __init__(self, cos: torch.Tensor, which: torch.Tensor):
        self.cos, self.which = cos, which

    def power(self, mats, gain_db=0.0) -> torch.Tensor:
        eta = mats.eta(torch.tensor([F]))[:, 0][self.which]
        r_te, _ = fresnel(eta, self.cos, K0, mats.thickness_m[self.which])
        s2 = mats.scattering[self.which] ** 2
        return (1e-6 * r_te.abs() ** 2 * (1.0 - s2 + 0.2 * s2))[:, None]


def _truth(s: float) -> MaterialParams:
    """A metal plate and 20 cm of concrete, both of scattering coefficient s."""
    p = MaterialParams(2)
    eps, sig1 = tabulated_values("concrete", F, p.sigma_exponent)
    p.set_values(0, eps_r=1.0, sigma_1ghz=1e7, scattering=s, thickness_m=0.01)
    p.set_values(1, eps_r=eps, sigma_1ghz=sig1, scattering=s, thickness_m=0.2)
    return p


def test_shared_scattering_is_one_value_that_set_values_sets_for_all():
    p = MaterialParams(3, scattering=0.2, shared_scattering=True)
    p.set_values(1, eps_r=4.0, scattering=0.45)
    s = p.values().scattering
    assert s.shape == (3,) and torch.allclose(s, torch.full((3,), 0.45, dtype=torch.float64))
    assert abs(float(p.values().eps_r[0]) - 3.0) < 1e-9 and abs(float(p.values().eps_r[1]) - 4.0) < 1e-9
    assert all(t is not p.t_s for t in _raw(p))          # a shared S is no one material's to swap
    q = MaterialParams(3, scattering=0.2)
    q.set_values(1, scattering=0.45)
    assert [round(float(x), 6) for x in q.values().scattering] == [0.2, 0.45, 0.2]
    assert any(t is q.t_s for t in _raw(q))


def test_a_metal_fixes_the_shared_scattering_and_with_it_the_dielectrics_reflection():
    rng = np.random.default_rng(0)
    n = 400
    cos = torch.as_tensor(np.cos(rng.uniform(0.0, 1.2, n)))
    which = torch.as_tensor(np.arange(n) % 2)
    plates = _Plates(cos, which)
    truth = _truth(0.3)
    with torch.no_grad():
        target = 10 * torch.log10(plates.power(truth.values())) + torch.as_tensor(rng.normal(0.0, 0.2, (n, 1)))
    cfg = PhysicalFitConfig(iterations=300, start_iterations=30, lr=0.05, shared_scattering=True, starts_kept=3)
    res = fit_materials(plates, 2, target.numpy(), cfg)
    v = res.params.values()
    g = v.normal_reflection(torch.tensor([F])).abs()[:, 0]
    g_true = truth.values().normal_reflection(torch.tensor([F])).abs()[:, 0]
    assert float(v.scattering[0]) == float(v.scattering[1])
    assert abs(float(v.scattering[0]) - 0.3) < 0.06
    assert float(g[0]) > 0.95                                  # the metal
    assert abs(float(g[1]) - float(g_true[1])) < 0.04          # concrete's 0.40


def test_room_config_shares_the_scattering_by_default_and_refuses_an_unknown_choice():
    import pytest

    from rfir_core.errors import ConfigError
    from rfir_stages.rf_fit.room_stage import room_config

    settings, fit_cfg, _ = room_config({})
    assert settings.scattering == "shared" and fit_cfg.shared_scattering
    settings, fit_cfg, _ = room_config({"room": {"scattering": "per_material"}})
    assert settings.scattering == "per_material" and not fit_cfg.shared_scattering
    with pytest.raises(ConfigError, match="rf_fit.room.scattering = 'each'"):
        room_config({"room": {"scattering": "each"}})
