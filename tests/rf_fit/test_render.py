"""The renderer against closed forms (docs/physics.md sections 4-5), occlusion, and grid invariance."""
import math

import numpy as np
import pytest
import torch

from rfir_cli.physics import C0
from rfir_cli.physics.gaussian_rf import bistatic_gaussian_response, covariance
from rfir_stages.geom import gaussians_from_mesh
from rfir_stages.rf_fit.antennas import AntennaPattern
from rfir_stages.rf_fit.occlusion import BruteForceOcclusion, TracerOcclusion
from rfir_stages.rf_fit.render import Materials, RenderSettings, build_cache, render, transmittances

from .helpers import DEG, bistatic, box_fields, db, geometry, radar, square

ISO = AntennaPattern("isotropic")


def mats(g, a=1.0, r=1.0, gamma=1.0):
    return Materials(torch.full((g,), a, dtype=torch.float64), torch.full((g,), r, dtype=torch.float64),
                     torch.full((g,), gamma, dtype=torch.complex128))


def test_matches_per_gaussian_physics_without_occlusion():
    torch.manual_seed(1)
    geom = geometry(box_fields(0.08, 0.05))
    g = geom.num
    tx = torch.randn(6, 3, dtype=torch.float64) * 2 + torch.tensor([3.0, 0, 0])
    rx = torch.randn(6, 3, dtype=torch.float64) * 2 + torch.tensor([3.0, 1, 0])
    links = bistatic(tx, rx, [2.4e9, 5.8e9])
    m = Materials(torch.rand(g, dtype=torch.float64), 1 + 5 * torch.rand(g, dtype=torch.float64),
                  torch.randn(g, dtype=torch.complex128))
    s = render(build_cache(geom, links, ISO, ISO, None, RenderSettings(visibility=False)), m)
    ref = bistatic_gaussian_response(geom.means, covariance(geom.log_scales, geom.rotations), geom.normals,
                                     links.tx_m, links.rx_m, links.freq_hz, m.roughness, m.gamma,
                                     rf_opacity=m.opacity).sum(1)
    np.testing.assert_allclose(s.numpy(), ref.numpy(), rtol=1e-10, atol=1e-30)


def test_single_gaussian_closed_form_with_visibility_traced():
    fields = gaussians_from_mesh(*square(0.02), spacing_m=0.05)    # one sub-triangle per face: 2 Gaussians
    fields = {k: v[:1] for k, v in fields.items()}
    fields["gaussians/means"] = np.zeros((1, 3))
    geom = geometry(fields)
    area = float(math.pi * torch.exp(geom.log_scales[0, :2]).prod())
    ranges = [2.0, 3.0, 5.0]
    gamma = 0.6 * np.exp(0.3j)
    freq = 2.4e9
    for r in ranges:
        links = radar([0.0], r, [freq], separation_m=0.0)         # radar at (r, 0, 0), facing the surfel
        cache = build_cache(geom, links, ISO, ISO, BruteForceOcclusion(geom), RenderSettings())
        s = render(cache, mats(1, a=0.8, gamma=gamma))[0, 0]
        expect = abs(gamma) ** 2 * 0.8**2 * area / (16 * math.pi**2 * r**4)
        np.testing.assert_allclose(abs(s) ** 2, expect, rtol=1e-6)
        k = 2 * math.pi * freq / C0
        assert abs(np.angle(complex(s) * np.exp(2j * k * r)) - 0.3) < 1e-6
        v, tb = transmittances(cache, torch.full((1,), 0.8, dtype=torch.float64))
        assert float(v) == 1.0 and abs(float(tb) - 1.0) < 1e-12


def test_plate_of_gaussians_at_normal_incidence_adds_in_phase():
    fields = gaussians_from_mesh(*square(0.3), spacing_m=0.04)
    geom = geometry(fields)
    r, freq = 60.0, 2.4e9                                            # far field of the 0.3 m plate
    links = radar([0.0], r, [freq], separation_m=0.0)
    cache = build_cache(geom, links, ISO, ISO, BruteForceOcclusion(geom), RenderSettings(grid_step_deg=0.5))
    v, tb = transmittances(cache, torch.ones(geom.num, dtype=torch.float64))
    assert float(v.min()) == 1.0 and float(tb.min()) > 0.999          # a surface does not shadow itself
    s = render(cache, mats(geom.num))[0, 0]
    areas = math.pi * torch.exp(geom.log_scales[:, :2]).prod(-1)
    expect = float(areas.sqrt().sum()) ** 2 / (16 * math.pi**2 * r**4)
    np.testing.assert_allclose(abs(s) ** 2, expect, rtol=2e-3)
    np.testing.assert_allclose(float(areas.sum()), 0.09, rtol=1e-9)   # the surfels tile the plate's area


def _occluded_scene():
    """A small surfel at the origin behind a large one (std 0.2 m) at x = 0.3, both facing +x."""
    small = gaussians_from_mesh(*square(0.02), spacing_m=0.05)
    fields = {k: np.concatenate([v[:1], v[:1]]) for k, v in small.items()}
    fields["gaussians/means"] = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.0]])
    fields["gaussians/log_scales"][1] = np.log([0.2, 0.2, 0.01])
    return geometry(fields)


def test_hidden_gaussian_contributes_nothing_and_opacity_controls_it():
    geom = _occluded_scene()
    links = radar([0.0], 3.0, [2.4e9], separation_m=0.0)                # radar at (3, 0, 0)
    cache = build_cache(geom, links, ISO, ISO, BruteForceOcclusion(geom), RenderSettings(learn_visibility=True))
    only_back = lambda a_front: Materials(torch.tensor([1.0, a_front], dtype=torch.float64),  # noqa: E731
                                          torch.ones(2, dtype=torch.float64),
                                          torch.tensor([1.0, 0.0], dtype=torch.complex128))
    alone = render(build_cache(geometry({"gaussians/" + k: getattr(geom, k)[:1].numpy() for k in
                                         ("means", "log_scales", "rotations", "normals")}),
                               links, ISO, ISO, None, RenderSettings(visibility=False)), mats(1))
    hidden = render(cache, only_back(1.0))
    assert abs(hidden[0, 0]) ** 2 < 1e-3 * abs(alone[0, 0]) ** 2
    transparent = render(cache, only_back(0.0))
    np.testing.assert_allclose(abs(transparent[0, 0]), abs(alone[0, 0]), rtol=1e-9)
    # gradients reach the occluder's opacity
    a = torch.tensor([1.0, 0.5], dtype=torch.float64, requires_grad=True)
    s = render(cache, Materials(a, torch.ones(2, dtype=torch.float64), torch.tensor([1.0, 0], dtype=torch.complex128)))
    (s.abs() ** 2).sum().backward()
    assert a.grad[1] < 0


def test_receiver_grid_refinement_changes_predictions_by_less_than_half_a_db():
    geom = geometry(box_fields(0.05, 0.03))
    links = radar(np.arange(0, 90, 15) * DEG + 0.1, 2.0, [2.4e9, 5.8e9], height_m=0.03)
    m = Materials(torch.full((geom.num,), 0.9, dtype=torch.float64), torch.full((geom.num,), 3.0, dtype=torch.float64),
                  torch.polar(torch.full((geom.num,), 0.7, dtype=torch.float64),
                              torch.linspace(0, 2, geom.num, dtype=torch.float64)))
    prov = BruteForceOcclusion(geom)
    out = [db(render(build_cache(geom, links, ISO, ISO, prov, RenderSettings(grid_step_deg=step)), m))
           for step in (1.0, 0.5)]
    assert np.max(np.abs(out[0] - out[1])) < 0.5


def test_tracer_and_brute_force_agree():
    geom = geometry(box_fields(0.05, 0.03))
    tracer = TracerOcclusion(geom)   # the CPU tracer is always built: no skip
    brute = BruteForceOcclusion(geom)
    o = torch.tensor([[1.5, 0.4, 0.2]], dtype=torch.float64).expand(geom.num, 3)
    ids = torch.arange(geom.num)
    for a, b in ((tracer.segment_hits(o, ids), brute.segment_hits(o, ids)),):
        assert torch.equal(a.query, b.query) and torch.equal(a.gaussian, b.gaussian)
        np.testing.assert_allclose(a.response, b.response, atol=1e-9)
        np.testing.assert_allclose(a.t_m, b.t_m, atol=1e-9)


def test_horn_pattern_is_the_simulators():
    from rfir_stages.simulate.antennas import Antenna

    horn = AntennaPattern("horn", hpbw_deg=40.0)
    d = torch.nn.functional.normalize(torch.randn(50, 3, dtype=torch.float64), dim=-1)
    axis = torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64)
    np.testing.assert_allclose(horn.gain(d, axis).numpy(), Antenna("horn", (1.0, 0.0, 0.0), 40.0).gain(d.numpy()),
                               rtol=1e-12)
    np.testing.assert_allclose(horn.boresight_gain, Antenna("horn", (1, 0, 0), 40.0).boresight_gain)


@pytest.mark.parametrize("provider", [BruteForceOcclusion, TracerOcclusion])
@pytest.mark.parametrize("monostatic", [True, False])
def test_frozen_visibility_equals_learned_at_the_same_opacities(provider, monostatic):
    """Frozen V and Tbar (one-pass transmittance, footprint sums composited by the provider) equal
    the learned path's (hit tables composited in torch), for the radar and for separate Tx / Rx."""
    geom = geometry(box_fields(0.05, 0.03))
    links = radar([0.3, 1.0, 2.5], 2.0, [2.4e9], height_m=0.02)
    if not monostatic:
        links = bistatic(links.tx_m, links.rx_m + torch.tensor([0.0, 0.4, 0.1], dtype=torch.float64), [2.4e9])
    # a tiny alpha_min: the learned tables hold hits down to G >= alpha_min, the frozen traces down
    # to a G >= alpha_min; with 1e-9 what the two keep differs by less than 1e-8 of transmittance
    prov = provider(geom, alpha_min=1e-9)
    a = torch.linspace(0.3, 0.95, geom.num, dtype=torch.float64)
    learned = transmittances(build_cache(geom, links, ISO, ISO, prov, RenderSettings(learn_visibility=True, t_stop=0)), a)
    frozen = transmittances(build_cache(geom, links, ISO, ISO, prov, RenderSettings(t_stop=0), frozen_opacity=a), a)
    for x, y in zip(learned, frozen):
        np.testing.assert_allclose(x.numpy(), y.numpy(), rtol=1e-7, atol=1e-12)
    assert float(learned[0].min()) < 0.1 < 0.99 < float(learned[0].max())   # some Gaussians are hidden


def test_frozen_visibility_with_early_stopping_differs_only_below_t_stop():
    geom = geometry(box_fields(0.05, 0.03))
    links = radar([0.3, 1.0, 2.5], 2.0, [2.4e9], height_m=0.02)
    prov = TracerOcclusion(geom)
    a = torch.full((geom.num,), 0.95, dtype=torch.float64)
    exact = transmittances(build_cache(geom, links, ISO, ISO, prov, RenderSettings(t_stop=0), frozen_opacity=a), a)
    stopped = transmittances(build_cache(geom, links, ISO, ISO, prov, RenderSettings(t_stop=1e-2), frozen_opacity=a), a)
    v, v_stop = exact[0].reshape(-1), stopped[0].reshape(-1)
    assert bool((v < 1e-2).any())                                      # some segments do stop early
    np.testing.assert_allclose(v_stop[v >= 1e-2].numpy(), v[v >= 1e-2].numpy(), rtol=1e-12)
    assert bool((v_stop[v < 1e-2] < 1e-2).all())
