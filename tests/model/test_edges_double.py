"""Doubly diffracted edge waves (docs/physics.md section 8.13): the wave diffracted at one edge of a plate,
carried across its face and diffracted again at the opposite edge, in H polarisation (E across the edges:
the hard case, whose field does not vanish on the face). Checked against the strip's second-order GTD
closed form (written out here) and a full-wave (BEM) curve of a PEC plate in H."""
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.special import fresnel

from rfir_core.physics.closed_forms import C0
from rfir_stages.model.edges import utd_transition
from rfir_stages.model.physical import MaterialParams, PairSettings, build_pairs, scattered_power
from rfir_stages.model.occlusion import make_provider

from .helpers import ISO, monostatic, plate_mesh, rcs_dbsm, surfels

PEC_LIKE = dict(eps_r=1.0, sigma_1ghz=1e7, scattering=1e-9, thickness_m=None)
BEM_H = Path(__file__).resolve().parent / "data" / "bem_plate_h_2g4.csv"
FAR_M = 200.0


def _rcs(geom, aspects, freq_hz, polarisation):
    _, links = monostatic(aspects, FAR_M, freq_hz)
    pairs = build_pairs(geom, links, ISO, ISO, make_provider("auto", geom),
                        PairSettings(edge_waves=True, polarisation=polarisation))
    mats = MaterialParams(1, **PEC_LIKE).values()
    p = scattered_power(pairs, torch.zeros(geom.num, dtype=torch.int64), mats).detach().numpy()[:, 0]
    return rcs_dbsm(np.maximum(p, 1e-300), FAR_M, freq_hz)


def _f(x):
    """Kouyoumjian-Pathak transition function, from the Fresnel integrals (exp(+j omega t))."""
    s, c = fresnel(np.sqrt(2 * x / math.pi))
    return 2j * np.sqrt(x) * np.exp(1j * x) * math.sqrt(math.pi / 2) * ((0.5 - c) - 1j * (0.5 - s))


def _strip_gtd_hard(theta_deg, freq_hz, a, second_order=True):
    """sigma (dBsm) of a square PEC plate of side a in its principal plane, E across the two edges that cross
    the plane (hard), theta from broadside. First order (Ross 1966): (a^2 / pi) |cos x - j sin x / sin theta|^2,
    x = k a sin theta, i.e. half the sum of Keller's backscatter brackets 1 + sec(phi) of the two edges
    (phi = pi / 2 +- theta from each edge's face). Higher orders, in units of Keller's
    C = -exp(-j pi / 4) / (2 sqrt(2 pi k)): a crossing of the face from edge to edge is
    h = C exp(-j k a) / sqrt(a) (the hard field on a zero-thickness plate is odd across it: the grazing waves
    of both faces diffract); an edge sends the radar's wave along the face with 2 sec(phi / 2), returns a wave
    from the face to the radar with the same, and sends a wave from the face back along it with 2.
    sec(phi / 2) -> F(2 k a cos^2(phi / 2)) / cos(phi / 2) (UTD) at the edge beyond which the radar lies
    (phi > pi / 2), so that it stays finite as the radar reaches the plate's plane. Paths: edge 1 -> edge 2
    (both ways), edge 1 -> 2 -> 1 (from each edge), and each of them with any number of further round trips
    (4 h^2 each: the geometric series)."""
    k = 2 * math.pi * freq_hz / C0
    t = np.radians(theta_deg)
    x = k * a * np.sin(t)
    bracket = (1 - 1 / np.sin(t)) * np.exp(1j * x) + (1 + 1 / np.sin(t)) * np.exp(-1j * x)
    if second_order:
        near, far = math.pi / 2 + t, math.pi / 2 - t          # the edge nearer the radar, the farther one

        def g(p):
            c = np.cos(p / 2)
            return np.where(p > math.pi / 2, _f(2 * k * a * np.where(p > math.pi / 2, c, 1.0) ** 2), 1.0) / c

        h = (-np.exp(-1j * math.pi / 4) / (2 * np.sqrt(2 * math.pi * k))) * np.exp(-1j * k * a) / np.sqrt(a)
        out_n, out_f = 2 * g(near), 2 * g(far)               # radar -> face, and face -> radar (reciprocal)
        paths = 2 * out_n * h * out_f \
            + out_n * h * 2 * h * out_n * np.exp(1j * x) + out_f * h * 2 * h * out_f * np.exp(-1j * x)
        bracket = bracket + paths / (1 - 4 * h**2)
    return 10 * np.log10(a**2 / math.pi * np.abs(bracket / 2) ** 2)


def test_utd_transition_limits():
    """F(X) -> 1 for large X, ~ sqrt(pi X) exp(j pi / 4) for small X; |F| < 1 between."""
    assert abs(utd_transition(np.array(400.0)) - 1) < 2e-3
    x = np.array(1e-6)
    assert abs(utd_transition(x) / (math.sqrt(math.pi * x) * np.exp(1j * math.pi / 4)) - 1) < 1e-2
    mid = utd_transition(np.linspace(0.01, 10, 50))
    assert np.all(np.abs(mid) < 1.0) and np.all(np.isfinite(mid))


@pytest.mark.parametrize("freq_hz,spacing_m", [(2.4e9, 0.03), (5.8e9, 0.02)])
def test_square_plate_h_polarisation_against_second_order_gtd(freq_hz, spacing_m):
    """A square PEC plate in its principal plane in H (E across the vertical edges), 60-84 degrees from
    broadside and 15-84: the model follows the strip's GTD with the waves crossing the face (first order, the
    doubly diffracted edge-to-edge paths, the return paths and the round trips) within 0.5 dB MAE, within
    1.0 dB at every aspect to 80 degrees; the first-order form alone differs from it by 3+ dB at 60-84. Beyond
    84 degrees the closed form falls as cos^4 while the plate's horizontal edges, seen nearly end-on, keep a
    first-order fringe (docs/physics.md section 8.13, left out; test_edges_grazing)."""
    a = 0.3
    geom, _ = surfels(*plate_mesh((0, 0, 0), (0, 1, 0), (0, 0, 1), a, a), spacing_m)
    theta = np.arange(15.0, 85.0, 1.0)
    closed = _strip_gtd_hard(theta, freq_hz, a)
    model = _rcs(geom, theta, freq_hz, "H")
    graze = theta >= 60
    assert np.abs(model - closed)[graze].mean() < 0.5 and np.abs(model - closed).mean() < 0.5
    assert np.abs(model - closed)[theta <= 80].max() < 1.0
    first = _strip_gtd_hard(theta, freq_hz, a, second_order=False)
    assert np.abs(first - closed)[graze].mean() > 3.0


def test_plate_h_against_the_full_wave_curve():
    """The H BEM curve of a 0.3 m PEC plate (tests/model/data/bem_plate_h_2g4.csv, made with
    `python -c "import numpy as np; from rfir_stages.fullwave.bem import bem_monostatic_rcs; from
    rfir_stages.fullwave.meshes import plate_screen; v, f = plate_screen(0.3, 16); p = np.radians(np.arange(0,
    91.0)); u = np.stack([np.cos(p), np.sin(p), 0 * p], 1); print(10 * np.log10(np.maximum(bem_monostatic_rcs(v,
    f, 2.4e9, u, 'H'), 1e-30)))"`, bempp-cl 0.4.2) against the model with perfect conductors and nothing fitted
    (3 cm surfels), every 2nd aspect within 40 dB of the peak: between 10 and 80 degrees from broadside within
    1.5 dB MAE (first-order edge waves alone: 3.0 dB), 50-80 degrees (the lobe the doubly diffracted wave
    makes, which the first order misses by 4-6 dB) within 2 dB; broadside unchanged."""
    from rfir_stages.fullwave.meshes import plate_screen

    rows = np.loadtxt(BEM_H, delimiter=",", comments="#", skiprows=4)[::2]
    phi, bem = rows[:, 0], rows[:, 1]
    keep = bem > bem.max() - 40
    phi, bem = phi[keep], bem[keep]
    geom, _ = surfels(*plate_screen(0.3, 4), 0.03)
    model = _rcs(geom, phi, 2.4e9, "H")
    wide = (phi > 10) & (phi < 80)
    assert np.abs(model - bem)[wide].mean() < 1.5
    lobe = (phi >= 50) & (phi <= 80)
    assert np.abs(model - bem)[lobe].mean() < 2.0
    assert abs(model[phi == 0][0] - bem[phi == 0][0]) < 0.3


def test_a_rectangles_edges_face_each_other_across_its_width():
    """0.3 (y) x 0.2 (z) m plate: nearly every edge segment has an opposite on the facing side, the distance
    across is the plate's other dimension, and each segment's straight run spans its side."""
    from .test_edges import _edges

    geom, _ = surfels(*plate_mesh((0, 0, 0), (0, 1, 0), (0, 0, 1), 0.3, 0.2), 0.02)
    e = _edges(geom)
    has = e.opposite >= 0
    assert float(e.length[has].sum()) > 0.9 * float(e.length.sum())
    vertical = has & (e.tangent[:, 2].abs() > 0.99)
    horizontal = has & (e.tangent[:, 1].abs() > 0.99)
    assert torch.allclose(e.width[vertical], torch.full_like(e.width[vertical], 0.3), atol=0.02)
    assert torch.allclose(e.width[horizontal], torch.full_like(e.width[horizontal], 0.2), atol=0.02)
    run = e.span[:, 1] - e.span[:, 0]
    assert float(run[vertical].min()) > 0.15 and float(run[horizontal].min()) > 0.25
    opp = e.opposite[has]
    assert bool((e.opposite[opp] >= 0).all())          # pairs are mutual (both paths)
