"""Each term of the RFIR forward model against a closed form (docs/physics.md sections 4-5)."""
import math

import numpy as np
import pytest
import torch

from rfir_cli.physics import C0, rcs_from_path_gain
from rfir_cli.physics.gaussian_rf import (bistatic_gaussian_response, covariance, projected_cross_section_m2,
                                          reflect, scattering_lobe)



@pytest.fixture(autouse=True)
def _float64():
    """These closed-form checks run in float64; restore the default so other tests see torch's own."""
    before = torch.get_default_dtype()
    torch.set_default_dtype(torch.float64)
    yield
    torch.set_default_dtype(before)


def disc(n=1, scale=0.05, flat=1e-4):
    """n flat Gaussians in the plane x = 0 (normal +x), spaced along y."""
    means = torch.zeros(n, 3)
    means[:, 1] = torch.linspace(-(n - 1) / 2, (n - 1) / 2, n) * 2 * scale
    log_scales = torch.log(torch.tensor([[flat, scale, scale]])).expand(n, 3)
    quats = torch.tensor([[1.0, 0, 0, 0]]).expand(n, 4)
    return means, covariance(log_scales, quats), torch.tensor([[1.0, 0, 0]]).expand(n, 3)


def test_projected_cross_section_sphere_and_tilted_disc():
    s = 0.2
    cov = covariance(torch.full((1, 3), math.log(s)), torch.tensor([[0.3, 0.1, -0.5, 0.8]]))
    u = torch.nn.functional.normalize(torch.randn(5, 1, 3), dim=-1)
    np.testing.assert_allclose(projected_cross_section_m2(cov, u), math.pi * s * s, rtol=1e-10)
    _, cov, _ = disc(scale=0.1)
    for theta in (0.0, 0.5, 1.2):
        u = torch.tensor([[[math.cos(theta), math.sin(theta), 0.0]]])
        np.testing.assert_allclose(projected_cross_section_m2(cov, u)[0, 0], math.pi * 0.01 * math.cos(theta),
                                   rtol=1e-4)


def test_lobe_peaks_in_the_specular_direction():
    normal = torch.tensor([0.0, 0.0, 1.0])
    incoming = torch.nn.functional.normalize(torch.tensor([1.0, 0.0, -1.0]), dim=0)
    mirror = reflect(incoming, normal)
    np.testing.assert_allclose(mirror, [2**-0.5, 0, 2**-0.5], atol=1e-12)
    angles = torch.linspace(0.05, math.pi - 0.05, 181)
    outs = torch.stack([torch.cos(angles), torch.zeros_like(angles), torch.sin(angles)], -1)
    step = float(angles[1] - angles[0])
    lobe_only = scattering_lobe(torch.ones_like(angles), outs @ mirror, torch.tensor(20.0))
    assert abs(float(angles[lobe_only.argmax()]) - math.pi / 4) <= step / 2
    # sqrt(cos theta_o) pulls the peak toward the normal (pi/2), less so as the lobe narrows.
    pulls = [float(angles[scattering_lobe(outs[:, 2], outs @ mirror, torch.tensor(r)).argmax()]) - math.pi / 4
             for r in (5.0, 20.0, 200.0)]
    assert pulls[0] > pulls[1] > pulls[2] >= 0 and pulls[2] < 0.01
    assert scattering_lobe(torch.tensor(-0.1), torch.tensor(1.0), torch.tensor(1.0)) == 0


def monostatic(means, cov, normals, ranges, freq, gamma=None, direction=(1.0, 0.0, 0.0)):
    d = torch.tensor(direction)
    radar = torch.as_tensor(ranges)[:, None] * d
    g = means.shape[0]
    gamma = gamma if gamma is not None else torch.ones(g, dtype=torch.complex128)
    return bistatic_gaussian_response(means, cov, normals, radar, radar, torch.tensor([freq]),
                                      torch.ones(g), gamma).sum(1)[:, 0]


def test_single_gaussian_free_space_energy_and_phase_versus_distance():
    means, cov, normals = disc(scale=0.05)
    freq, ranges = 2.4e9, torch.tensor([2.0, 3.0, 4.5, 7.0])
    s = monostatic(means, cov, normals, ranges, freq, gamma=torch.tensor([0.7 * np.exp(0.4j)]))
    area = math.pi * 0.05**2
    # |S|^2 = |Gamma|^2 A / (16 pi^2 r^4) at normal incidence: energy falls as r^-4.
    np.testing.assert_allclose(s.abs() ** 2, 0.49 * area / (16 * math.pi**2 * ranges**4), rtol=1e-6)
    k = 2 * math.pi * freq / C0
    phase = np.angle(s.numpy() * np.exp(1j * 2 * k * ranges.numpy()))
    np.testing.assert_allclose(phase, 0.4, atol=1e-9)      # the carrier phase is -2 k r plus angle(Gamma)
    sigma = rcs_from_path_gain(s.abs().numpy() ** 2, ranges.numpy(), freq)
    np.testing.assert_allclose(sigma, sigma[0], rtol=1e-9)  # RCS does not depend on range


def test_plate_of_gaussians_adds_coherently_at_normal_incidence_only():
    means, cov, normals = disc(n=9, scale=0.05)
    freq, r = 5.8e9, torch.tensor([400.0])                 # far field of the 0.9 m line
    one = monostatic(*disc(n=1, scale=0.05), r, freq).abs() ** 2
    nine = monostatic(means, cov, normals, r, freq).abs() ** 2
    np.testing.assert_allclose(nine / one, 81.0, rtol=1e-3)   # in phase: N^2
    tilt = math.radians(10.0)
    off = monostatic(means, cov, normals, r, freq, direction=(math.cos(tilt), math.sin(tilt), 0.0)).abs() ** 2
    assert off / nine < 0.05                                   # path differences 2 k y sin(theta) dephase the row


def test_receiver_behind_the_surface_gets_nothing():
    means, cov, normals = disc()
    tx = torch.tensor([[2.0, 0.0, 0.0]])
    rx = torch.tensor([[-2.0, 0.5, 0.0]])
    out = bistatic_gaussian_response(means, cov, normals, tx, rx, torch.tensor([2.4e9]), torch.ones(1),
                                     torch.ones(1, dtype=torch.complex128))
    assert out.abs().max() == 0
