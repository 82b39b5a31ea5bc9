"""The 90-degree PEC dihedral in H polarisation (E across its fold and outer edges: the hard case) against a
full-wave (BEM) curve, tests/model/data/bem_dihedral_h_2g4.csv (its command in the file's header, bempp-cl
0.4.2), by aspect region as in docs/po.md ("Full-wave check"): the flash (the bisector +-35 degrees), the
single-plate flashes (+-5 degrees of 0/90/180) and the rest within 40 dB of the peak; and the wave between an
outer edge and the fold along the fold's outer face (docs/physics.md section 8.13, `edges._fold_terms`):
Keller's coefficients against their closed forms, and the dihedral with and without it."""
import math
from pathlib import Path

import numpy as np

import rfir_stages.model.edges as edges_module
from rfir_core.physics.closed_forms import C0
from rfir_stages.model.edges import wedge_grazing_vertex

from .helpers import surfels
from .test_edges import _ang, _fullwave, _rcs

BEM_DIHEDRAL_H = Path(__file__).resolve().parent / "data" / "bem_dihedral_h_2g4.csv"
FREQ_HZ = 2.4e9


def _fixture():
    """(phi_deg [91], bem_dbsm [91]) of the fixture (comment lines and the column names skipped)."""
    lines = [ln for ln in BEM_DIHEDRAL_H.read_text().splitlines() if ln and not ln.startswith("#")]
    rows = np.loadtxt(lines[1:], delimiter=",")
    return rows[:, 0], rows[:, 1]


def _regions(phi, bem):
    flash = _ang(phi, 45) <= 35
    plates = np.zeros_like(flash)
    for centre in (0, 90, 180):
        plates |= _ang(phi, centre) <= 5
    top = bem > bem.max() - 40
    return flash & top, plates & top, ~(flash | plates) & top


def test_fixture_is_symmetric_and_has_the_plates_flashes():
    """The BEM curve is symmetric about the bisector (0-90 degrees; the mesh is), and each plate seen at its
    normal (0, 90: inner faces; 180: an outer face) is within 0.5 dB of a flat plate's 4 pi A^2 / lambda^2."""
    phi, bem = _fixture()
    inside = phi <= 90
    assert np.abs(bem[inside] - bem[inside][::-1]).max() < 0.01
    broadside = 10 * np.log10(4 * math.pi * 0.09**2 / (C0 / FREQ_HZ) ** 2)
    for centre in (0.0, 90.0, 180.0):
        assert abs(bem[phi == centre][0] - broadside) < 0.5


def _dihedral():
    from rfir_stages.fullwave.meshes import dihedral_screen

    return surfels(*dihedral_screen(0.3, 0.3, 4), 0.03)[0]


def _without_fold_terms(monkeypatch):
    """Edges found without their fold links (`Edges.fold` all -1): the model as it was without `_fold_terms`."""
    found = edges_module._fold_edges
    monkeypatch.setattr(edges_module, "_fold_edges", lambda *a: tuple(
        np.full_like(x, -1 if x.dtype.kind == "i" else 0) for x in found(*a)))


def test_wedge_grazing_vertex_closed_forms():
    """Keller's hard coefficient between the radar and a wave grazing along face 0, relative to the half-plane's
    at phi = 0: a half-plane (n = 2) is sec(phi / 2) on the near side (phi <= pi / 2, F = 1); a 90-degree fold
    seen from outside (n = 3/2) is -(2 sin(pi / n) / n) / (cos(pi / n) - cos(phi / n)) there, 4 / (3 sqrt(3))
    at grazing; at the shadow boundary of the grazing wave (phi -> pi) the UTD transition keeps it finite,
    +-sqrt(2 pi kw) on either side (the jump that makes the total field continuous) plus the regular term
    cot(pi / n) / n (0 for a half-plane), and beyond the normal but far from the boundary (kw large) it tends
    to Keller's."""
    phi = np.linspace(0.0, 0.5 * math.pi, 7)
    assert np.allclose(wedge_grazing_vertex(phi, 2.0, 15.0), 1 / np.cos(phi / 2), atol=1e-9)
    n = 1.5
    keller = -(2 * math.sin(math.pi / n) / n) / (math.cos(math.pi / n) - np.cos(phi / n))
    assert np.allclose(wedge_grazing_vertex(phi, n, 15.0), keller, atol=1e-9)
    assert abs(wedge_grazing_vertex(0.0, n, 15.0) - 4 / (3 * math.sqrt(3))) < 1e-9
    kw = 15.0
    for n in (2.0, 1.5):
        lo, hi = wedge_grazing_vertex(np.array([math.pi - 1e-4, math.pi + 1e-4]), n, kw)
        jump, even = 0.5 * (lo - hi), 0.5 * (lo + hi)       # the singular term is odd in pi - phi
        assert abs(abs(jump) - math.sqrt(2 * math.pi * kw)) < 0.01 * math.sqrt(2 * math.pi * kw)
        assert abs(even - 1 / (n * math.tan(math.pi / n))) < 1e-3        # the regular term, cot(pi / n) / n
    far = np.array([2.0, 2.6])                                # beyond the normal, away from the boundary
    assert np.allclose(wedge_grazing_vertex(far, 2.0, 1e6), 1 / np.cos(far / 2), rtol=1e-3)


def test_dihedral_h_against_the_full_wave_curve():
    """The model with perfect conductors and nothing fitted (3 cm surfels, double bounce and edge waves with
    the waves between the outer edges and the fold) against the fixture: flash within 2 dB MAE (measured 1.78;
    the double bounce's level, PO alone 1.62), single-plate flashes within 0.5 dB (0.26), the rest within
    3.2 dB (2.90; without the fold term 4.00, see below) while physical optics alone is more than 4.5 dB off
    there (4.99)."""
    phi, bem = _fixture()
    flash, plates, rest = _regions(phi, bem)
    geom = _dihedral()
    model = _rcs(geom, phi, FREQ_HZ, True, second_order=True, polarisation="H")
    po = _rcs(geom, phi, FREQ_HZ, False, second_order=True, polarisation="H")
    assert np.abs(model - bem)[flash].mean() < 2.0
    assert np.abs(model - bem)[plates].mean() < 0.5
    assert np.abs(model - bem)[rest].mean() < 3.2
    assert np.abs(po - bem)[rest].mean() > 4.5


def test_the_fold_term_is_what_brings_the_rest_closer(monkeypatch):
    """Without the fold term the rest is more than 3.2 dB off (4.00: the assertion above fails); the term
    reaches only radars outside the fold's wedge (0-88 degrees, in the concave corner, unchanged within 0.01
    dB) and moves 104-124 degrees by more than 1 dB at every aspect (1.4-12.7); the full-wave V curve (E along
    the fold: soft, no such term) moves by less than 0.02 dB at any aspect (measured 0.010, at 119 degrees: the
    hard share of V at the outer edges' rounded ends)."""
    phi, bem = _fixture()
    _, _, rest = _regions(phi, bem)
    geom = _dihedral()
    c = _fullwave("dihedral")
    vphi = np.asarray(c["phi_deg"])
    with_h = _rcs(geom, phi, FREQ_HZ, True, second_order=True, polarisation="H")
    with_v = _rcs(geom, vphi, c["freq_hz"], True, second_order=True, polarisation="V")
    _without_fold_terms(monkeypatch)
    without_h = _rcs(geom, phi, FREQ_HZ, True, second_order=True, polarisation="H")
    without_v = _rcs(geom, vphi, c["freq_hz"], True, second_order=True, polarisation="V")
    assert np.abs(without_h - bem)[rest].mean() > 3.2
    assert np.abs(with_h - without_h)[phi <= 88].max() < 0.01
    assert np.abs(with_h - without_h)[(phi >= 104) & (phi <= 124)].min() > 1.0   # where the term acts
    assert np.abs(with_v - without_v).max() < 0.02
