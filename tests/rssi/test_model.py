"""The RSSI model against closed forms and independent references (docs/physics.md section 6)."""
import math

import numpy as np
import pytest
import torch

import rfir_tracer
from rfir_cli.physics.closed_forms import friis_path_gain
from rfir_stages.rf_fit.antennas import AntennaPattern
from rfir_stages.rf_fit.occlusion import BruteForceOcclusion, TracerOcclusion
from rfir_stages.rf_fit.render import LinkSet, Materials, RenderSettings, build_cache, render
from rfir_stages.rf_fit.rssi_model import (LinkTerms, ProbeField, RssiModel, link_terms, los_transmittance,
                                           predict_db, render_nlos)

from ..rf_fit.helpers import geometry
from .helpers import scene_fields

F = 2.4e9


def _terms(dist, los_v, g=3):
    m = len(dist)
    return LinkTerms(torch.zeros(m, g), torch.ones(m, g), torch.ones(m, g, dtype=torch.complex64),
                     torch.as_tensor(dist, dtype=torch.float64), torch.as_tensor(los_v, dtype=torch.float64), F)


def test_direct_path_alone_is_friis():
    dist = np.array([1.0, 2.5, 7.0, 13.0])
    model = RssiModel(torch.arange(3))
    got = predict_db(_terms(dist, np.ones(4)), model).detach().numpy()
    np.testing.assert_allclose(got, 10 * np.log10(friis_path_gain(dist, F)), atol=1e-9)


def test_visibility_scales_the_direct_path_and_ablation_ignores_it():
    dist, v = np.array([3.0, 3.0]), np.array([1.0, 0.1])
    friis = 10 * np.log10(friis_path_gain(dist, F))
    weighted = predict_db(_terms(dist, v), RssiModel(torch.arange(3))).detach().numpy()
    np.testing.assert_allclose(weighted, friis + 20 * np.log10(v), atol=1e-9)
    plain = predict_db(_terms(dist, v), RssiModel(torch.arange(3), weighting=False)).detach().numpy()
    np.testing.assert_allclose(plain, friis, atol=1e-9)


def test_los_transmittance_matches_tracer_and_brute_force_through_a_wall():
    fields, _ = scene_fields(0.6)
    geom = geometry(fields)
    a = torch.full((geom.num,), 0.7, dtype=torch.float64)
    tx = torch.tensor([[1.0, 0.8, 1.5], [1.0, 0.5, 1.0], [0.5, 2.5, 1.2]], dtype=torch.float64)
    rx = torch.tensor([[3.0, 0.8, 1.0], [1.5, 2.5, 1.0], [3.5, 2.2, 1.0]], dtype=torch.float64)  # wall, open, door
    v_tr = los_transmittance(TracerOcclusion(geom), tx, rx, a)
    v_bf = los_transmittance(BruteForceOcclusion(geom), tx, rx, a)
    np.testing.assert_allclose(v_tr.numpy(), v_bf.numpy(), rtol=1e-6, atol=1e-9)
    scene = rfir_tracer.GaussianScene(geom.means, geom.log_scales, geom.rotations, normals=geom.normals)
    # the providers keep hits with response G >= 1e-3; the tracer's alpha_min applies to a G
    ref = rfir_tracer.trace(scene, tx, rx - tx, opacities=a, t_min=0.0, t_max=1.0, alpha_min=0.7e-3, t_stop=0.0)
    np.testing.assert_allclose(v_tr.numpy(), ref.transmittance.numpy(), rtol=1e-6, atol=1e-9)
    assert v_tr[0] < 0.5 and v_tr[1] > 0.9   # through the partition vs in the open (grazing the table)


def test_nlos_equals_the_rcs_renderer_without_visibility():
    fields, _ = scene_fields(0.6)
    geom = geometry(fields)
    g = geom.num
    gen = torch.Generator().manual_seed(0)
    tx = torch.tensor([[0.8, 0.7, 2.0], [3.1, 2.2, 2.0]], dtype=torch.float64)
    rx = torch.tensor([[1.5, 2.0, 1.0], [2.6, 0.5, 1.0]], dtype=torch.float64)
    ant = AntennaPattern("isotropic")
    ones = torch.ones(2, g)
    idx = torch.arange(2)
    terms = link_terms(geom, tx, rx, F, ones, idx, ones, idx, torch.ones(2), ant)
    model = RssiModel(torch.arange(g))
    with torch.no_grad():
        model.rf.theta_a.copy_(torch.randn(g, generator=gen, dtype=torch.float64))
        model.rf.theta_phi.copy_(torch.randn(g, generator=gen, dtype=torch.float64))
    mats = model.rf.materials()
    z = torch.tensor([[0.0, 0.0, 1.0]] * 2, dtype=torch.float64)
    cache = build_cache(geom, LinkSet(tx, rx, torch.tensor([F]), z, z), ant, ant, None, RenderSettings(visibility=False))
    ref = render(cache, Materials(mats.opacity.detach(), mats.roughness.detach(), mats.gamma.detach()))[:, 0]
    got = render_nlos(terms, model).detach()
    np.testing.assert_allclose(got.numpy(), ref.numpy(), rtol=2e-5)


def test_probe_field_is_exact_on_a_linear_field():
    origin, step, shape = np.array([0.5, 0.5, 0.5]), 0.5, (4, 3, 2)
    field = ProbeField(origin, step, shape, torch.zeros(0))
    pts = field.points()
    coef = torch.tensor([[0.3, -0.2], [0.1, 0.5], [-0.4, 0.2]], dtype=torch.float64)
    field.values = (pts @ coef + 1.0).float()
    q = torch.tensor([[0.6, 0.9, 0.7], [1.9, 1.4, 0.95], [0.5, 0.5, 0.5]], dtype=torch.float64)
    np.testing.assert_allclose(field.at(q).numpy(), (q @ coef + 1.0).numpy(), atol=1e-6)
    np.testing.assert_allclose(field.at(pts).numpy(), field.values.numpy(), atol=1e-6)


@pytest.mark.parametrize("weighting", [True, False])
def test_gradients_reach_the_learned_parts(weighting):
    fields, _ = scene_fields(0.6)
    geom = geometry(fields)
    g = geom.num
    tx = torch.tensor([[0.8, 0.7, 2.0]], dtype=torch.float64)
    rx = torch.tensor([[2.6, 2.0, 1.0]], dtype=torch.float64)
    ones, idx = torch.ones(1, g), torch.zeros(1, dtype=torch.int64)
    terms = link_terms(geom, tx, rx, F, ones, idx, ones, idx, torch.tensor([0.5]), AntennaPattern("isotropic"))
    model = RssiModel(torch.arange(g), weighting=weighting)
    with torch.no_grad():
        model.los.head.weight.normal_()
    predict_db(terms, model).sum().backward()
    assert model.rf.theta_phi.grad.abs().sum() > 0 and model.nlos_gain_db.grad.abs() > 0
    grad = model.los.head.weight.grad
    assert (grad is not None and float(grad.abs().sum()) > 0) == weighting   # the ablation has no LoS network
    assert math.isfinite(float(model.rf.s_tx_db.grad[0]))


@pytest.mark.parametrize("kind", ["isotropic", "dipole"])
def test_fast_omni_geometry_equals_the_renderers(kind):
    from rfir_stages.rf_fit.render import link_geometry
    from rfir_stages.rf_fit.rssi_model import OmniGeometry, _path_m, omni_link_geometry

    fields, _ = scene_fields(0.6)
    geom = geometry(fields)
    gen = torch.Generator().manual_seed(1)
    tx = torch.rand(5, 3, generator=gen, dtype=torch.float64) * torch.tensor([4.0, 3.0, 2.5])
    rx = torch.rand(5, 3, generator=gen, dtype=torch.float64) * torch.tensor([4.0, 3.0, 2.5])
    ant = AntennaPattern(kind)
    z = torch.tensor([[0.0, 0.0, 1.0]] * 5, dtype=torch.float64)
    ref = link_geometry(geom, LinkSet(tx, rx, torch.tensor([F]), z, z), ant, ant)
    og = OmniGeometry(geom)
    got = omni_link_geometry(og, tx, rx, ant)
    scale = float(ref[0].abs().max())
    np.testing.assert_allclose(got[0].double().numpy(), ref[0].numpy(), rtol=1e-4, atol=1e-5 * scale)
    np.testing.assert_allclose(got[1].double().numpy(), ref[1].numpy(), atol=1e-5)
    np.testing.assert_allclose(_path_m(og, tx, rx).numpy(), ref[2].numpy(), rtol=1e-12)
