"""Fitting: parameter recovery on data made by the renderer, and generalisation over aspect."""
import math

import numpy as np
import pytest
import torch

from rfir_stages.geom import gaussians_from_mesh
from rfir_stages.predict.baselines import aspect_baselines
from rfir_stages.rf_fit.antennas import AntennaPattern
from rfir_stages.rf_fit.fit import FitConfig, fit, predict_db
from rfir_stages.rf_fit.params import RFParams
from rfir_stages.rf_fit.render import Materials, RenderSettings, build_cache, render

from .helpers import DEG, bistatic, box_fields, db, geometry, square

ISO = AntennaPattern("isotropic")


def _two_plates():
    """Two 0.2 m squares facing +x, at y = -1 (label 0) and y = +1 (label 1)."""
    parts = []
    for label, y in ((0, -1.0), (1, 1.0)):
        v, f = square(0.2)
        v[:, 1] += y
        fields = gaussians_from_mesh(v, f, 0.04, labels=np.full(len(f), label))
        parts.append(fields)
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def test_fit_recovers_known_materials():
    fields = _two_plates()
    geom = geometry(fields)
    labels = torch.as_tensor(fields["gaussians/labels"])
    # bistatic links sweeping through the specular directions of both plates (Tx fixed on +x)
    angles = np.linspace(-70, 70, 21) * DEG
    rx = np.stack([4 * np.cos(angles), 4 * np.sin(angles), np.full_like(angles, -0.2)], 1)
    tx = np.tile([[4.0, 0.0, 0.2]], (len(angles), 1))
    links = bistatic(tx, rx, [2.4e9, 2.5e9])
    cache = build_cache(geom, links, ISO, ISO, None, RenderSettings(visibility=False))
    truth = {"roughness": torch.tensor([3.0, 12.0], dtype=torch.float64),
             "gamma_abs": torch.tensor([0.8, 0.3], dtype=torch.float64)}
    m = Materials(torch.ones(geom.num, dtype=torch.float64), truth["roughness"][labels],
                  truth["gamma_abs"][labels].to(torch.complex128))
    meas = db(render(cache, m))
    params = RFParams(labels, 2, opacity=0.999, roughness=6.0, gamma_abs=0.5)
    cfg = FitConfig(iterations=200, lr=0.15, learn=("roughness", "gamma_abs"), loss="db_mse")
    params.s_tx_db.data.zero_()
    res = fit(cache, meas, params, cfg)
    # init_system_gain moved s_tx; gamma magnitudes are recovered up to that common factor
    got_r = np.array([res.roughness[labels == 0][0], res.roughness[labels == 1][0]])
    got_g = np.array([res.gamma_abs[labels == 0][0], res.gamma_abs[labels == 1][0]])
    np.testing.assert_allclose(got_r, truth["roughness"].numpy(), rtol=0.05)
    np.testing.assert_allclose(got_g[1] / got_g[0], 0.3 / 0.8, rtol=0.05)
    assert res.train_mae_db < 0.1 < res.initial_mae_db


def test_fit_generalises_between_training_aspects_better_than_nearest_aspect():
    """Data: the renderer on a box with random materials at 5 deg steps; train even, test odd."""
    fields = box_fields(0.06, 0.03)
    geom = geometry(fields)
    g = geom.num
    gen = torch.Generator().manual_seed(3)
    truth = Materials(torch.full((g,), 0.9, dtype=torch.float64), 1 + 4 * torch.rand(g, generator=gen, dtype=torch.float64),
                      torch.polar(0.3 + 0.6 * torch.rand(g, generator=gen, dtype=torch.float64),
                                  2 * math.pi * torch.rand(g, generator=gen, dtype=torch.float64)))
    aspects = np.arange(0, 180, 5) * DEG + 0.05
    from .helpers import radar

    links = radar(aspects, 2.5, [2.4e9], height_m=0.02)
    cache_all = build_cache(geom, links, ISO, ISO, None, RenderSettings(visibility=False))
    meas = db(render(cache_all, truth))
    train, test = np.arange(0, len(aspects), 2), np.arange(1, len(aspects), 2)
    links_tr = radar(aspects[train], 2.5, [2.4e9], height_m=0.02)
    cache_tr = build_cache(geom, links_tr, ISO, ISO, None, RenderSettings(visibility=False))
    params = RFParams(torch.arange(g), 1, opacity=0.9, roughness=2.0, gamma_abs=0.5)
    fit(cache_tr, meas[train], params, FitConfig(iterations=100, lr=0.05))
    with torch.no_grad():
        pred = predict_db(cache_all, params).numpy()
    model_mae = np.mean(np.abs(pred[test] - meas[test]))
    base = aspect_baselines(aspects, np.full(len(aspects), 2.5), meas, train, test)
    nearest_mae = np.nanmean(np.abs(base["nearest"] - meas[test]))
    assert model_mae < nearest_mae, (model_mae, nearest_mae)


def test_incoherent_params_have_no_coherent_sum_and_do_not_learn_gamma():
    from rfir_stages.rf_fit.params import RFParams

    p = RFParams(torch.arange(5), 1, diffuse=0.2, coherent=False)
    m = p.materials()
    assert torch.equal(m.gamma, torch.zeros(5, dtype=torch.complex128)) and m.diffuse is not None
    names = [g["name"] for g in p.groups(["opacity", "gamma_abs", "gamma_phase", "diffuse"])]
    assert names == ["opacity", "diffuse"]
    assert not p.theta_g.requires_grad and not p.theta_phi.requires_grad
    with pytest.raises(ValueError, match="diffuse term"):
        RFParams(torch.arange(5), 1, diffuse=None, coherent=False)
