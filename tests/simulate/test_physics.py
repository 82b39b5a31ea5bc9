"""Checks of the radio simulator against closed-form physics it did not write (issue 3).

Each test runs Sionna RT through the same code the stage uses (scene export, solve, path
combination, antenna patterns) and compares with a formula. Sizes are small: a few solves each.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

pytest.importorskip("sionna.rt")

from rfir_core.physics.antennas import horn_boresight_gain  # noqa: E402
from rfir_stages.simulate.radio_scene import C0, MaterialEffects, load_radio_scene  # noqa: E402
from rfir_stages.simulate.rcs import RadarGrid, object_radius, simulate_monostatic  # noqa: E402
from rfir_stages.simulate.scenes import build_scene, ground_plate, plate  # noqa: E402
from rfir_stages.simulate.solve import PhysicsEffects, rcs_dbsm_from_gain, solve_links  # noqa: E402

from rfir_core.progress import NullProgress  # noqa: E402

FREQS = (2.4e9, 5.8e9)
SPECULAR_ONLY = PhysicsEffects(max_depth=1, diffuse=False, refraction=False, samples_per_src=100_000,
                               combine="coherent")


def db(x):
    return 10 * np.log10(np.asarray(x, dtype=float))


def fresnel_tm(eta: complex, cos_theta: np.ndarray) -> np.ndarray:
    """TM (parallel) reflection coefficient of a half-space, ITU-R P.2040 eq. (31) convention."""
    sin2 = 1.0 - cos_theta ** 2
    root = np.sqrt(eta - sin2 + 0j)
    return (eta * cos_theta - root) / (eta * cos_theta + root)


def metal_eta(freq_hz: float) -> complex:
    """Complex relative permittivity of ITU 'metal': eps_r = 1, sigma = 1e7 S/m."""
    eps0 = 8.8541878128e-12
    return 1.0 - 1j * 1e7 / (eps0 * 2 * math.pi * freq_hz)


@pytest.mark.parametrize("freq_hz", FREQS)
def test_friis_free_space(tmp_path, freq_hz):
    scene = load_radio_scene(build_scene("empty"), tmp_path, freq_hz)
    d = np.array([1.0, 3.0, 10.0])
    rx = np.stack([d, np.zeros(3), np.full(3, 1.5)], 1)
    out = solve_links(scene, [0.0, 0.0, 1.5], rx, freq_hz, SPECULAR_ONLY)
    lam = C0 / freq_hz
    expected = db((lam / (4 * math.pi * d)) ** 2)
    np.testing.assert_allclose(db(out.power[:, 0]), expected, atol=0.1)


@pytest.mark.parametrize("freq_hz", FREQS)
def test_two_ray_over_metal_plate(tmp_path, freq_hz):
    scene = load_radio_scene(ground_plate(40.0), tmp_path, freq_hz)
    h_t, h_r = 2.0, 1.5
    x = np.linspace(1.0, 15.0, 97)
    rx = np.stack([x, np.zeros_like(x), np.full_like(x, h_r)], 1)
    out = solve_links(scene, [0.0, 0.0, h_t], rx, freq_hz, SPECULAR_ONLY)
    lam, k = C0 / freq_hz, 2 * math.pi * freq_hz / C0
    d1 = np.hypot(x, h_t - h_r)
    d2 = np.hypot(x, h_t + h_r)
    gamma = fresnel_tm(metal_eta(freq_hz), (h_t + h_r) / d2)  # V-pol antennas: TM over a horizontal plate
    h = lam / (4 * math.pi) * (np.exp(-1j * k * d1) / d1 + gamma * np.exp(-1j * k * d2) / d2)
    expected = db(np.abs(h) ** 2)
    got = db(out.power[:, 0])
    assert expected.max() - expected.min() > 15, "the line must cross interference nulls"
    np.testing.assert_allclose(got, expected, atol=0.1)


@pytest.mark.parametrize("freq_hz", FREQS)
@pytest.mark.parametrize("focus", [True, False], ids=["focused", "full-sphere"])
def test_monostatic_plate_echo(tmp_path, freq_hz, focus):
    """4 x 4 m metal plate facing the radar: P_R/P_T = G0^2 (lambda / (8 pi r))^2, RCS = pi r^2."""
    spec = plate(4.0)
    scene = load_radio_scene(spec, tmp_path, freq_hz)
    ranges = np.array([2.0, 3.0, 5.0])
    grid = RadarGrid(np.array([0.0]), ranges, np.zeros(3), 0.002)
    hpbw = 40.0
    physics = PhysicsEffects(max_depth=2, diffuse=False, refraction=False, samples_per_src=20_000,
                             combine="coherent")
    raw = simulate_monostatic(scene, grid, object_radius(spec), [freq_hz], [[freq_hz]], physics, hpbw,
                              focus=focus, progress=NullProgress(), label="plate")
    g0 = horn_boresight_gain(hpbw)
    lam = C0 / freq_hz
    expected = db(g0 ** 2 * (lam / (8 * math.pi * ranges)) ** 2)
    np.testing.assert_allclose(db(raw.power[:, 0]), expected, atol=0.1)
    rcs = rcs_dbsm_from_gain(raw.power, ranges, [freq_hz], g0)[:, 0]
    np.testing.assert_allclose(rcs, db(math.pi * ranges ** 2), atol=0.1)


def test_reciprocity_classroom(tmp_path):
    """Swap Tx and Rx: received power changes by < 0.1 dB (specular + refraction, depth 3).

    Ten random pairs inside the classroom. (A hand-picked pair whose desk reflection point fell
    exactly on a desk-top edge found that path in one direction only: an edge-grazing specular
    point is a numerical tie, not a reciprocity failure of the field computation.)
    """
    spec = build_scene("classroom")
    scene = load_radio_scene(spec, tmp_path, 2.4e9)
    physics = PhysicsEffects(max_depth=3, diffuse=False, refraction=True, samples_per_src=100_000,
                             combine="coherent")
    rng = np.random.default_rng(3)
    a = rng.uniform([0.5, 0.5, 1.0], [8.5, 6.5, 2.6], (10, 3)).round(2)
    b = rng.uniform([0.5, 0.5, 1.0], [8.5, 6.5, 2.6], (10, 3)).round(2)
    forward = np.array([solve_links(scene, a[i], b[i:i + 1], 2.4e9, physics).power[0, 0] for i in range(len(a))])
    backward = np.array([solve_links(scene, b[i], a[i:i + 1], 2.4e9, physics).power[0, 0] for i in range(len(a))])
    assert np.all(forward > 0)
    np.testing.assert_allclose(db(forward), db(backward), atol=0.1)


def test_focused_sampling_matches_full_sphere(tmp_path):
    """Diffuse + specular echo of the H target at an oblique aspect: the focused cone with 3e4 rays
    and Sionna's own full-sphere sampling with 3e6 rays agree (same estimator, denser)."""
    spec = build_scene("h-target")
    scene = load_radio_scene(spec, tmp_path, 5.8e9, MaterialEffects(0.5, "lambertian"))
    grid = RadarGrid(np.deg2rad([30.0]), np.array([3.0]), np.zeros(3), 0.002)

    def echo(focus, samples):
        physics = PhysicsEffects(max_depth=2, diffuse=True, refraction=False, samples_per_src=samples,
                                 max_num_paths_per_src=10 ** 6)
        raw = simulate_monostatic(scene, grid, object_radius(spec), [5.8e9], [[5.8e9]], physics, 40.0,
                                  focus=focus, progress=NullProgress(), label="h")
        return db(raw.power[0, 0]), raw.num_diffuse[0, 0]

    focused, n_focused = echo(True, 30_000)
    full, n_full = echo(False, 3_000_000)
    assert n_focused > 1000 and n_full > 300
    assert focused == pytest.approx(full, abs=0.5)


def _wall(material: str, thickness_m: float, size_m: float = 30.0):
    """The plane x = 0 as one two-sided rectangle of an ITU material and slab thickness (as the rooms' walls)."""
    import dataclasses

    spec = plate(size_m)
    spec.objects[0] = dataclasses.replace(spec.objects[0], radio_material=material, thickness_m=thickness_m)
    return spec


def _eta(material: str, freq_hz: float) -> complex:
    from rfir_core.physics.materials import itu_law, permittivity

    eps, sig = itu_law(material, freq_hz)
    return complex(permittivity(float(eps), float(sig), freq_hz))


@pytest.mark.parametrize("material, thickness_m", [("brick", 0.12), ("plasterboard", 0.025), ("glass", 0.006)])
def test_wall_transmission_is_the_slab_formula_of_the_room_model(tmp_path, material, thickness_m):
    """A link through one wall: Sionna's refracted path equals Friis times the co-polar slab transmission of
    rfir's materials (the coefficient the room model applies per crossing: ITU-R P.2040 multiple internal
    reflections, T_TE on (e . s) s and T_TM on (e . p) p), at incidence 0-57 degrees, pure TE and mixed."""
    import torch

    from rfir_core.physics.materials import slab_transmission
    from rfir_core.physics.polarisation import antenna_polarisation

    f = 2.4e9
    scene = load_radio_scene(_wall(material, thickness_m), tmp_path, f)
    physics = PhysicsEffects(max_depth=1, diffuse=False, refraction=True, samples_per_src=200_000, combine="coherent")
    tx = np.array([-2.0, 0.0, 0.0])
    y, z = np.meshgrid([0.0, 1.0, 3.0, 6.0], [0.0, 2.0])
    rx = np.stack([np.full(y.size, 2.0), y.ravel(), z.ravel()], 1)
    got = db(solve_links(scene, tx, rx, f, physics).power[:, 0])
    d = np.linalg.norm(rx - tx, axis=1)
    k = (rx - tx) / d[:, None]
    n = np.array([1.0, 0.0, 0.0])
    s = np.cross(k, n)
    s = np.where(np.linalg.norm(s, axis=1, keepdims=True) > 1e-9, s, [0.0, 0.0, 1.0])   # normal incidence: any
    s /= np.linalg.norm(s, axis=1, keepdims=True)
    p = np.cross(k, s)
    t_te, t_tm = (c.numpy() for c in slab_transmission(torch.tensor(_eta(material, f)), torch.tensor(np.abs(k @ n)),
                                                        2 * math.pi * f / C0, thickness_m))
    e = antenna_polarisation(k, "V")                    # the same vector at both ends: k is unchanged
    co = t_te * np.sum(e * s, 1) ** 2 + t_tm * np.sum(e * p, 1) ** 2
    want = db((C0 / f / (4 * math.pi * d)) ** 2 * np.abs(co) ** 2)
    assert want.max() - want.min() > 1.0, "the loss must change with the angle of incidence"
    np.testing.assert_allclose(got, want, atol=0.02)


def test_reflection_off_a_dielectric_wall_is_the_slab_formula_of_the_room_model(tmp_path):
    """Both antennas in front of a 20 cm concrete wall, in a horizontal plane (V polarisation: pure TE):
    Sionna's direct + reflected field is the two-ray sum with rfir's slab R_TE, interference included."""
    from rfir_core.physics.materials import fresnel

    f = 2.4e9
    scene = load_radio_scene(_wall("concrete", 0.2), tmp_path, f)
    physics = PhysicsEffects(max_depth=1, diffuse=False, refraction=True, samples_per_src=200_000, combine="coherent")
    tx = np.array([-1.0, 0.0, 0.0])
    y = np.linspace(0.0, 8.0, 41)
    rx = np.stack([np.full_like(y, -0.6), y, np.zeros_like(y)], 1)
    got = db(solve_links(scene, tx, rx, f, physics).power[:, 0])
    k0 = 2 * math.pi * f / C0
    d1 = np.linalg.norm(rx - tx, axis=1)
    d2 = np.hypot(y, 1.6)                               # to the image at x = +1
    r_te = fresnel(_eta("concrete", f), 1.6 / d2, k0, 0.2)[0].numpy()
    want = db(np.abs(C0 / f / (4 * math.pi) * (np.exp(-1j * k0 * d1) / d1 + r_te * np.exp(-1j * k0 * d2) / d2)) ** 2)
    assert want.max() - want.min() > 6.0, "the line must cross interference minima"
    np.testing.assert_allclose(got, want, atol=0.05)


@pytest.mark.slow
def test_the_rssi_path_buffer_keeps_every_path_of_a_full_grid(tmp_path):
    """Sionna drops paths beyond max_num_paths_per_src for all receivers of a solve together, silently. At the
    configured buffer, one of the flat's transmitters solved for about 950 receivers at once gives what twice the
    buffer gives (a buffer of 2e6 moved the median link by 0.36 dB). Slow: two solves of 5-9 GB."""
    from rfir_core.config import load_defaults
    from rfir_stages.simulate.radio_scene import MaterialEffects
    from rfir_stages.simulate.rssi import clear_of_objects

    rssi = load_defaults()["simulate"]["rssi"]
    spec = build_scene("flat")
    scene = load_radio_scene(spec, tmp_path, 2.4e9, MaterialEffects(0.3, "directive", 4))
    xs, ys = np.meshgrid(np.arange(0.125, 9.0, 0.25), np.arange(0.125, 7.0, 0.25))
    rx = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, 1.0)], 1)
    rx = rx[clear_of_objects(spec, rx, 0.05)]                      # not inside the fridge or against a wall
    assert len(rx) > 800

    def solve(cap):
        physics = PhysicsEffects(max_depth=3, diffuse=True, refraction=True, samples_per_src=int(rssi["samples_per_src"]),
                                 max_num_paths_per_src=int(cap), combine="power")
        return db(solve_links(scene, [7.0, 5.5, 2.2], rx, 2.4e9, physics).power[:, 0])

    configured = int(rssi["max_num_paths_per_src"])
    d = np.abs(solve(configured) - solve(2 * configured))
    assert np.median(d) < 0.05 and d.mean() < 0.3, (np.median(d), d.mean())


def test_a_survey_over_channels_is_the_mean_power_of_the_two_ray_sum_over_them(tmp_path):
    """simulate.rssi.channels_hz: the paths solved at the centre, each link's power the mean over BLE's three
    advertising channels, against the two-ray closed form evaluated at each channel and averaged."""
    from rfir_stages.simulate.rssi import simulate_rssi

    centre, channels = 2.44e9, (2.402e9, 2.426e9, 2.480e9)
    scene = load_radio_scene(ground_plate(40.0), tmp_path, centre)
    h_t, h_r = 2.0, 1.5
    x = np.linspace(1.0, 15.0, 97)
    rx = np.stack([x, np.zeros_like(x), np.full_like(x, h_r)], 1)
    _, power, *_ = simulate_rssi(scene, np.array([[0.0, 0.0, h_t]]), rx, [centre], SPECULAR_ONLY, NullProgress(),
                                 "two-ray", channels_hz=channels)
    d1, d2 = np.hypot(x, h_t - h_r), np.hypot(x, h_t + h_r)
    expected = np.zeros_like(x)
    for f in channels:
        lam, k = C0 / f, 2 * math.pi * f / C0
        gamma = fresnel_tm(metal_eta(f), (h_t + h_r) / d2)
        expected += np.abs(lam / (4 * math.pi) * (np.exp(-1j * k * d1) / d1 + gamma * np.exp(-1j * k * d2) / d2)) ** 2
    expected /= len(channels)
    np.testing.assert_allclose(db(power[:, 0]), db(expected), atol=0.1)
    lam, k = C0 / centre, 2 * math.pi * centre / C0
    one = np.abs(lam / (4 * math.pi) * (np.exp(-1j * k * d1) / d1 - np.exp(-1j * k * d2) / d2)) ** 2
    assert db(expected).min() > db(one).min() + 5, "averaging over channels must fill the deepest fade"
