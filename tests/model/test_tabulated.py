"""tabulated.take_tabulated: a fitted material the links cannot tell from a tabulated one is taken as it; one
they can is kept; a name's material is preferred; the error never drifts beyond the margin.

The links are synthetic: link m reflects off material 0 at incidence angle theta_m and crosses material 1 at
the same angle, its path gain 20 log10 |R_TE| + 20 log10 |T_TE| (materials.fresnel, slab_transmission) plus a
constant, with a deterministic noise."""
from __future__ import annotations

import math

import numpy as np
import torch

from rfir_stages.model.identifiability import block_standard_error
from rfir_core.physics.materials import C0, fresnel, slab_transmission
from rfir_stages.model.physical import MaterialParams
from rfir_stages.model.tabulated import candidates, named_material, take_tabulated, tabulated_values

F = 2.4e9
K0 = 2 * math.pi * F / C0


def _predictor(cos: torch.Tensor):
    def predict(params: MaterialParams) -> torch.Tensor:
        v = params.values()
        eta = v.eta(torch.tensor([F]))[:, 0]
        r_te, _ = fresnel(eta[0], cos, K0, v.thickness_m[0])
        t_te, _ = slab_transmission(eta[1], cos, K0, v.thickness_m[1])
        return (20 * torch.log10(r_te.abs().clamp_min(1e-12)) + 20 * torch.log10(t_te.abs().clamp_min(1e-12))
                - 60.0)[:, None]
    return predict


def _params(*materials) -> MaterialParams:
    """MaterialParams of (eps_r, sigma at F [S/m], thickness [m]) per material, S = 0."""
    p = MaterialParams(len(materials))
    for i, (eps, sig, th) in enumerate(materials):
        p.set_values(i, eps_r=eps, sigma_1ghz=sig / (F / 1e9) ** p.sigma_exponent, scattering=0.0, thickness_m=th)
    return p


def _concrete():
    eps, sig1 = tabulated_values("concrete", F, 1.0)
    return eps, sig1 * F / 1e9, 0.2


UNLISTED = (12.0, 0.5, 0.04)     # no tabulated material: a dense lossy 4 cm slab


def _links(truth: MaterialParams, n: int, noise_db: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    cos = torch.as_tensor(np.cos(rng.uniform(0.0, 1.3, n)))
    pred = _predictor(cos)
    with torch.no_grad():
        target = pred(truth) + torch.as_tensor(rng.normal(0.0, noise_db, (n, 1)))
    return pred, target


def test_a_material_the_links_cannot_tell_from_concrete_is_taken_as_concrete_and_an_unlisted_one_is_kept():
    pred, target = _links(_params(_concrete(), UNLISTED), 400, 0.5)
    fitted = _params((5.6, 0.08, 0.26), UNLISTED)          # what a fit might end at: near concrete, thicker
    with torch.no_grad():
        before = ((pred(fitted) - target) ** 2)[:, 0]
    taken = take_tabulated(pred, fitted, target.numpy(), F, ["wall", "partition"])
    assert [(t.index, t.key) for t in taken] == [(0, "concrete")]
    v = fitted.values()
    assert abs(float(v.eps_r[0]) - 5.24) < 1e-6
    assert abs(float(v.eps_r[1]) - UNLISTED[0]) < 1e-6 and abs(float(v.thickness_m[1]) - UNLISTED[2]) < 1e-9
    with torch.no_grad():
        d = ((pred(fitted) - target) ** 2)[:, 0] - before
    assert float(d.mean()) <= block_standard_error(d)


def test_a_material_the_links_determine_stays_as_fitted():
    """With the fitted material the truth and quiet links, every tabulated candidate costs many standard errors."""
    pred, target = _links(_params(UNLISTED, UNLISTED), 400, 0.1)
    fitted = _params(UNLISTED, UNLISTED)
    assert take_tabulated(pred, fitted, target.numpy(), F, ["a", "b"]) == []
    assert abs(float(fitted.values().eps_r[0]) - UNLISTED[0]) < 1e-6


def test_a_name_that_names_a_material_takes_it_where_compatible():
    """Noisy links of a thin marble slab, which glass fits nearly as well: a "pane" is taken as marble (the lowest
    error), a "glass_partition" as glass. A conductor fitted short of metal is taken as metal."""
    marble = (7.074, 0.0055 * 2.4 ** 0.9262, 0.01)
    pred, target = _links(_params(marble, UNLISTED), 30, 3.0, seed=3)
    for name, want in (("pane", "marble"), ("glass_partition", "glass")):
        fitted = _params((7.2, 0.013, 0.011), UNLISTED)
        taken = take_tabulated(pred, fitted, target.numpy(), F, [name, "partition"])
        assert {t.index: t.key for t in taken}[0] == want
    metal_pred, metal_target = _links(_params((1.0, 1e7, 0.002), UNLISTED), 200, 0.3, seed=4)
    fitted = _params((24.0, 2e5, 0.01), UNLISTED)
    taken = take_tabulated(metal_pred, fitted, metal_target.numpy(), F, ["cabinet", "partition"])
    assert [(t.index, t.key) for t in taken] == [(0, "metal")]


def test_replacements_in_turn_stay_within_one_standard_error_of_the_lowest_error():
    """Two materials, each within one standard error of the fitted state when replaced alone, and the second
    within it after the first, but both together beyond it: only one is taken. The predictor is linear in eps_r
    along two orthogonal patterns of the links (alternating signs), so the two increases add."""
    m = 400
    rng = np.random.default_rng(11)
    u = torch.ones(m, 1, dtype=torch.float64)
    w = torch.as_tensor((-1.0) ** np.arange(m))[:, None]
    noise = torch.as_tensor(rng.normal(0.0, 1.0, (m, 1)))
    noise = noise - noise.mean()
    target = noise - w * (noise * w).mean()          # no mean along either pattern: each increase is k^2 / 4
    fitted_eps = (5.74, 5.74)                       # concrete (5.24) the nearest tabulated eps_r of both

    def ratio(d):
        return float(d.mean()) / block_standard_error(d)

    for k in np.linspace(0.02, 0.4, 200):           # the slope that puts each replacement alone near 0.8 SE
        def pred(params, k=k):
            e = params.values().eps_r
            return k * (e[0] - fitted_eps[0]) * u + k * (e[1] - fitted_eps[1]) * w
        with torch.no_grad():
            err = lambda p: ((pred(p) - target) ** 2)[:, 0]     # noqa: E731
            base = err(_params((5.74, 0.1, 0.2), (5.74, 0.1, 0.2)))
            one = err(_params((5.24, 0.1, 0.2), (5.74, 0.1, 0.2)))
            other = err(_params((5.74, 0.1, 0.2), (5.24, 0.1, 0.2)))
            both = err(_params((5.24, 0.1, 0.2), (5.24, 0.1, 0.2)))
        if max(ratio(one - base), ratio(other - base)) > 0.75:
            break
    assert ratio(one - base) <= 1.0 and ratio(other - base) <= 1.0
    assert ratio(both - one) <= 1.0 and ratio(both - other) <= 1.0     # each, after the other, within the margin
    assert ratio(both - base) > 1.0                                     # together, beyond it
    fitted = _params((5.74, 0.1, 0.2), (5.74, 0.1, 0.2))
    taken = take_tabulated(pred, fitted, target.numpy(), F, ["a", "b"])
    assert len(taken) == 1 and taken[0].key == "concrete"
    with torch.no_grad():
        assert ratio(((pred(fitted) - target) ** 2)[:, 0] - base) <= 1.0


def test_names_and_candidates():
    assert named_material("glass_partition") == "glass" and named_material("Metal-Cabinet") == "metal"
    assert named_material("woodland") is None and named_material("desk") is None
    keys = {k for k, _ in candidates(F, 0.07)}
    assert "concrete" in keys and "metal" in keys and "vacuum" not in keys
    assert "floorboard" not in keys                  # tabulated for 50-100 GHz only
    assert "wet_ground" not in keys and "wet_ground" in {k for k, _ in candidates(F, 0.07, "wet_ground")}
    assert sorted(th for k, th in candidates(F, 0.07) if k == "concrete") == [0.07, 0.2]
    assert [th for k, th in candidates(F, 0.07) if k == "metal"] == [0.07]
