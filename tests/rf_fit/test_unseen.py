"""Gaussians no training link sees take their seen neighbours' materials (rf_fit/unseen.py)."""
import numpy as np
import torch

from rfir_stages.geom import gaussians_from_mesh
from rfir_stages.rf_fit.antennas import AntennaPattern
from rfir_stages.rf_fit.fit import FitConfig, FitResult, fit
from rfir_stages.rf_fit.params import RFParams
from rfir_stages.rf_fit.render import RenderSettings, build_cache
from rfir_stages.rf_fit.unseen import fill_unseen, unseen_mask

from .helpers import DEG, bistatic, geometry, square


def _result(g):
    ramp = np.linspace(0.1, 0.9, g)
    return FitResult(opacity=ramp.copy(), roughness=1 + 10 * ramp, gamma_abs=ramp[::-1].copy(),
                     gamma_phase_rad=np.full(g, 0.5), s_tx_db=np.zeros(1), diffuse=ramp * 0.2,
                     diffuse_roughness=2 + ramp, loss_curve=np.zeros(1), train_mae_db=0.0, initial_mae_db=0.0,
                     iterations=1, wall_time_s=0.0)


def test_unseen_take_the_median_of_the_nearest_seen_of_their_own_label():
    means = np.array([[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [0.3, 0, 0], [5, 0, 0], [5.1, 0, 0]], float)
    labels = np.array([0, 0, 0, 1, 1, 1])
    res = _result(6)
    opacity0 = res.opacity.copy()
    unseen = np.array([False, False, False, True, False, False])   # label 1, but nearest to label 0 in space
    assert fill_unseen(res, unseen, means, labels, k=2) == 1
    assert np.isclose(res.opacity[3], np.median(opacity0[[4, 5]]))   # its own object's Gaussians, not the closer ones
    assert np.array_equal(res.opacity[:3], opacity0[:3]) and np.isclose(res.gamma_phase_rad[3], 0.5)
    # an object with nothing seen borrows from the nearest seen Gaussians of any object
    res = _result(6)
    unseen = np.array([False, False, False, True, True, True])
    assert fill_unseen(res, unseen, means, labels, k=1) == 3
    assert np.allclose(res.opacity[3:], opacity0[2])


def test_unseen_mask_is_zero_gradient_only():
    e = np.array([0.0, 1e-15, 1e-3, 1.0, 2.0])
    assert unseen_mask(e).tolist() == [True, True, False, False, False]
    assert not unseen_mask(np.zeros(3)).any()


def test_fit_records_no_exposure_for_a_gaussian_the_links_cannot_see():
    v, f = square(0.2)
    fields = gaussians_from_mesh(v, f, 0.05, labels=np.zeros(len(f), int))
    g = len(fields["gaussians/means"])
    geom = geometry(fields)
    angles = np.linspace(-40, 40, 9) * DEG
    rx = np.stack([4 * np.cos(angles), 4 * np.sin(angles), np.zeros_like(angles)], 1)
    links = bistatic(np.tile([[4.0, 0.0, 0.1]], (len(angles), 1)), rx, [2.4e9])
    iso = AntennaPattern("isotropic")
    cache = build_cache(geom, links, iso, iso, None, RenderSettings(visibility=False))
    cache.amp_geo[:, 0] = 0.0   # one Gaussian no link reaches: it contributes nothing, so no gradient
    params = RFParams(torch.arange(g), 1, diffuse=0.1)
    meas = np.full((len(angles), 1), -80.0)
    res = fit(cache, meas, params, FitConfig(iterations=5, checkpoint_every=0))
    mask = unseen_mask(res.extra["exposure"])
    assert mask[0] and mask.sum() == 1
