"""Issue 12: the PO RCS solver against closed forms (plate, sphere, dihedral) and its kernels."""
from __future__ import annotations

import numpy as np
import pytest

from rfir_stages.po import (dihedral_mesh, fresnel, icosphere, itu_reflection_coefficient, plate_mesh, po_rcs,
                            po_scattered_field, relative_permittivity, triangle_phase_factor)

C0 = 299_792_458.0
FREQS = np.array([2.4e9, 5.8e9])
LAM = C0 / FREQS
FAR = 1e4  # m: plane-wave incidence in the far-field mode (only the direction matters)


def db(x):
    return 10.0 * np.log10(x)


def monostatic_xz(theta_rad):
    """Radar directions in the x-z plane, theta from +z."""
    th = np.asarray(theta_rad, float)
    return FAR * np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], 1)


# ------------------------------------------------------------------------------------------------
# the triangle integral
# ------------------------------------------------------------------------------------------------
def _quad_triangle(tri, q, k, n=48):
    """Gauss-Legendre on the Duffy-mapped square: reference for (1/A) int exp(j k q.(r - c)) dS."""
    x, w = np.polynomial.legendre.leggauss(n)
    x, w = 0.5 * (x + 1), 0.5 * w
    U, T = np.meshgrid(x, x, indexing="ij")
    W = np.outer(w, w) * (1 - U)
    V = (1 - U) * T
    c = tri.mean(0)
    P = tri[0] + U[..., None] * (tri[1] - tri[0]) + V[..., None] * (tri[2] - tri[0])
    return 2.0 * np.sum(W * np.exp(1j * k * (P - c) @ q))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_triangle_integral_matches_quadrature(seed):
    rng = np.random.default_rng(seed)
    tri = rng.normal(size=(3, 3)) * 0.1
    c = tri.mean(0)
    n = np.cross(tri[1] - tri[0], tri[2] - tri[0])
    n /= np.linalg.norm(n)
    qs = [rng.normal(size=3), n * 1.7, n + 1e-7 * rng.normal(size=3)]
    ks = np.array([1.0, 30.0, 120.0, 400.0])
    for q in qs:
        alpha = np.array([[(tri[i] - c) @ q for i in range(3)]])
        got = triangle_phase_factor(alpha, ks)[0]
        ref = np.array([_quad_triangle(tri, q, k) for k in ks])
        np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9)


def test_triangle_integral_smooth_in_degenerate_cases():
    """Across the Taylor/closed-form switch and with coincident vertex phases the value is smooth."""
    ks = np.linspace(0.3, 0.7, 4001)  # spread k * 1.0 crosses the 0.5 rad switch
    for alpha in ([0.0, 0.0, 1.0], [0.0, 1.0, 1.0], [0.0, 0.3, 1.0], [0.0, 1e-13, 1.0]):
        v = triangle_phase_factor(np.array([alpha]), ks)[0]
        d2 = np.abs(np.diff(v, 2))  # second differences of a smooth function: O(dk^2)
        assert d2.max() < 1e-7, alpha
    one = triangle_phase_factor(np.array([[0.2, 0.2, 0.2]]), np.array([3.0, 50.0]))[0]
    np.testing.assert_allclose(one, np.exp(1j * np.array([3.0, 50.0]) * 0.2), atol=1e-15)


# ------------------------------------------------------------------------------------------------
# square plate
# ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [1, 6])
@pytest.mark.parametrize("pol", ["V", "H"])
@pytest.mark.parametrize("mat", [-1.0, "metal"])
def test_plate_broadside(n, pol, mat):
    L = 0.5
    v, f = plate_mesh(L, L, n)
    tx = monostatic_xz([0.0])
    sig = po_rcs(v, f, mat, tx, tx, FREQS, polarization=pol)[0]
    ref = 4 * np.pi * (L * L) ** 2 / LAM**2
    assert np.all(np.abs(db(sig / ref)) < 0.2)


@pytest.mark.parametrize("pol", ["V", "H"])
def test_plate_pattern_sinc2_and_nulls(pol):
    """sigma(theta) = 4 pi A^2/lambda^2 cos^2(theta) sinc^2(k L sin theta) (PO, rotation about an
    edge axis); first nulls at sin(theta) = lambda / (2 L) within 0.5 degree, 2.4 and 5.8 GHz."""
    L = 0.5
    v, f = plate_mesh(L, L, 3)
    th = np.radians(np.linspace(-20.0, 20.0, 2001))  # 0.02 degree steps
    tx = monostatic_xz(th)
    sig = po_rcs(v, f, "pec", tx, tx, FREQS, polarization=pol, max_facet_edge_m=0)  # exact: no split needed
    for j, lam in enumerate(LAM):
        k = 2 * np.pi / lam
        ref = 4 * np.pi * L**4 / lam**2 * np.cos(th) ** 2 * np.sinc(k * L * np.sin(th) / np.pi) ** 2
        main = ref > 1e-3 * ref.max()
        assert np.abs(db(sig[main, j] / ref[main])).max() < 0.2
        null = np.degrees(np.arcsin(lam / (2 * L)))
        for side in (+1, -1):
            s = sig[:, j][side * th > 0]
            a = np.degrees(np.abs(th[side * th > 0]))
            order = np.argsort(a)
            s, a = s[order], a[order]
            i = np.nonzero((s[1:-1] < s[:-2]) & (s[1:-1] < s[2:]))[0][0] + 1
            assert abs(a[i] - null) < 0.5, (lam, a[i], null)


def test_plate_bistatic_specular():
    """Bistatic specular: sigma = 4 pi (A cos theta)^2 / lambda^2 for a PEC plate (PO)."""
    L = 0.4
    v, f = plate_mesh(L, L, 2)
    th = np.radians([10.0, 30.0, 50.0])
    tx = monostatic_xz(th)
    rx = monostatic_xz(-th)
    for pol in ("V", "H"):
        sig = po_rcs(v, f, "pec", tx, rx, FREQS, polarization=pol)
        ref = 4 * np.pi * (L * L * np.cos(th)[:, None]) ** 2 / LAM[None, :] ** 2
        assert np.abs(db(sig / ref)).max() < 0.05


def test_plate_shadowed_by_plate_in_front():
    """A small plate hidden behind a bigger one adds nothing (ray-cast shadowing); alone it does."""
    vb, fb = plate_mesh(0.6, 0.6, 2)
    vs, fs = plate_mesh(0.2, 0.2, 1)
    vs = vs + np.array([0.05, 0.0, -0.3])
    v = np.concatenate([vb, vs])
    f = np.concatenate([fb, fs + len(vb)])
    tx = monostatic_xz(np.radians([0.0, 3.0]))
    both = po_scattered_field(v, f, "pec", tx, tx, FREQS)
    front = po_scattered_field(vb, fb, "pec", tx, tx, FREQS)
    np.testing.assert_allclose(both, front, rtol=1e-12, atol=1e-12)
    back = po_scattered_field(vs, fs, "pec", tx, tx, FREQS)
    assert np.all(np.abs(back) > 0.1)


def test_plate_near_field_tends_to_far_field():
    L = 0.3
    v, f = plate_mesh(L, L, 12)
    far = po_rcs(v, f, "pec", monostatic_xz([0.05]), monostatic_xz([0.05]), FREQS)
    for r, tol in ((1000.0, 0.01), (20.0, 0.5)):
        tx = r * np.array([[np.sin(0.05), 0.0, np.cos(0.05)]])
        near = po_rcs(v, f, "pec", tx, tx, FREQS, near_field=True)
        assert np.abs(db(near / far)).max() < tol


# ------------------------------------------------------------------------------------------------
# sphere and dihedral
# ------------------------------------------------------------------------------------------------
def test_sphere_optical_rcs():
    a = 0.3  # ka = 15 (2.4 GHz), 36 (5.8 GHz)
    v, f = icosphere(a, 5)  # 20480 facets, edge ~ 1.6 cm
    d = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.3, -0.5, 0.8]])
    tx = FAR * d / np.linalg.norm(d, axis=1, keepdims=True)
    sig = po_rcs(v, f, "metal", tx, tx, FREQS)
    assert np.abs(db(sig / (np.pi * a * a))).max() < 1.0


@pytest.mark.parametrize("pol", ["V", "H"])
def test_dihedral_peak_with_second_order(pol):
    a, b = 0.4, 0.25  # fold length a, plate width b
    v, f = dihedral_mesh(a, b, 2)
    tx = FAR * np.array([[1.0, 0.0, 1.0]]) / np.sqrt(2.0)
    ref = 8 * np.pi * a**2 * b**2 / LAM**2
    sig2 = po_rcs(v, f, "metal", tx, tx, FREQS, second_order=True, polarization=pol)[0]
    assert np.abs(db(sig2 / ref)).max() < 1.0
    sig1 = po_rcs(v, f, "metal", tx, tx, FREQS, second_order=False, polarization=pol)[0]
    assert np.all(db(sig1 / ref) < -15.0)  # the peak is a double-bounce return


def test_dihedral_second_order_near_field_and_chunking():
    a, b = 0.3, 0.2
    v, f = dihedral_mesh(a, b, 1)
    d = np.array([[1.0, 0.0, 1.0]]) / np.sqrt(2.0)
    far = po_scattered_field(v, f, "pec", FAR * d, FAR * d, FREQS, second_order=True)
    near = po_scattered_field(v, f, "pec", 200.0 * d, 200.0 * d, FREQS, second_order=True, near_field=True)
    assert np.abs(db(np.abs(near) ** 2 / np.abs(far) ** 2)).max() < 0.3
    tiny = po_scattered_field(v, f, "pec", FAR * d, FAR * d, FREQS, second_order=True, chunk_facets=256,
                              chunk_elements=300)
    np.testing.assert_allclose(tiny, far, rtol=1e-10, atol=1e-12)


# ------------------------------------------------------------------------------------------------
# materials, chunking, API
# ------------------------------------------------------------------------------------------------
def test_materials_fresnel():
    r_te, r_tm = fresnel(relative_permittivity("pec", 1e9), np.array([1.0, 0.5, 0.0]))
    np.testing.assert_allclose(r_te, -1)
    np.testing.assert_allclose(r_tm, 1)
    eta = relative_permittivity("concrete", 2.4e9)
    assert abs(eta.real - 5.24) < 1e-12 and eta.imag < 0
    g = itu_reflection_coefficient("concrete", 2.4e9)
    assert abs(g - (1 - np.sqrt(eta)) / (1 + np.sqrt(eta))) < 1e-12
    assert abs(itu_reflection_coefficient("metal", 5.8e9) + 1) < 1e-3
    # Brewster angle of a lossless dielectric: R_TM = 0
    e = 4.0
    cb = np.cos(np.arctan(np.sqrt(e)))
    assert abs(fresnel(e + 0j, cb)[1]) < 1e-12
    # a vanishing slab reflects nothing; a thick lossy slab reflects like a half-space
    assert abs(itu_reflection_coefficient("glass", 5e9, 1.0, "TE", thickness_m=1e-9)) < 1e-6
    thick = itu_reflection_coefficient("metal", 5e9, 0.7, "TM", thickness_m=0.01)
    assert abs(thick - itu_reflection_coefficient("metal", 5e9, 0.7, "TM")) < 1e-9
    # per-facet name arrays
    gs = itu_reflection_coefficient(np.array(["metal", "wood", "metal"]), 2.4e9)
    assert gs.shape == (3,) and gs[0] == gs[2]


def test_dielectric_plate_scales_with_gamma_squared():
    L = 0.3
    v, f = plate_mesh(L, L, 1)
    tx = monostatic_xz([0.0])
    pec = po_rcs(v, f, "pec", tx, tx, FREQS)[0]
    for mat in ("concrete", "wood", "glass"):
        sig = po_rcs(v, f, mat, tx, tx, FREQS)[0]
        gam = itu_reflection_coefficient(mat, FREQS)
        np.testing.assert_allclose(sig, pec * np.abs(gam) ** 2, rtol=1e-9)
    # callable Gamma(f) and a per-face array give the same
    sig_c = po_rcs(v, f, lambda fr: np.full(len(f), itu_reflection_coefficient("wood", fr)), tx, tx, FREQS)[0]
    sig_w = po_rcs(v, f, np.array(["wood"] * len(f)), tx, tx, FREQS)[0]
    np.testing.assert_allclose(sig_c, sig_w, rtol=1e-9)


def test_chunking_and_frequency_reuse_do_not_change_results():
    v, f = icosphere(0.1, 3)
    th = np.radians(np.linspace(0, 180, 7))
    tx = monostatic_xz(th)
    rx = monostatic_xz(th + 0.3)
    freqs = np.linspace(2.3e9, 2.5e9, 9)
    a = po_scattered_field(v, f, "metal", tx, rx, freqs)
    b = po_scattered_field(v, f, "metal", tx, rx, freqs, chunk_facets=256, chunk_elements=1000)
    np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-15)
    for j in (0, 4, 8):
        c = po_scattered_field(v, f, "metal", tx, rx, freqs[j:j + 1])
        np.testing.assert_allclose(c[:, 0], a[:, j], rtol=1e-12, atol=1e-15)


def test_closed_mesh_two_sided_equals_one_sided():
    v, f = icosphere(0.2, 3)
    tx = monostatic_xz(np.radians([0.0, 40.0, 90.0]))
    a = po_scattered_field(v, f, "pec", tx, tx, FREQS, two_sided=True)
    b = po_scattered_field(v, f, "pec", tx, tx, FREQS, two_sided=False)
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)


def test_progress_and_shapes():
    v, f = plate_mesh(0.2, 0.2, 1)
    calls = []
    tx = monostatic_xz(np.radians(np.arange(5)))
    s = po_scattered_field(v, f, -1, tx, tx, [2.4e9], progress=lambda d, t: calls.append((d, t)))
    assert s.shape == (5, 1) and s.dtype == complex
    assert calls[-1] == (5, 5)
    with pytest.raises(ValueError):
        po_scattered_field(v, f, -1, tx, tx[:3], [2.4e9])
    with pytest.raises(ValueError):
        po_scattered_field(v, f, "unobtainium", tx, tx, [2.4e9])


def _cat(*meshes):
    vs, fs, off = [], [], 0
    for v, f in meshes:
        vs.append(v)
        fs.append(f + off)
        off += len(v)
    return np.concatenate(vs), np.concatenate(fs)


def test_partial_shadow_refinement():
    """A plate half hidden behind another: the split-and-cast refinement of partly lit facets
    matches a mesh holding only the lit part (exact shadow line from the geometry)."""
    th = 0.02
    xs = -0.2 * np.tan(th)  # shadow line on the rear plate
    front = plate_mesh(0.3, 0.3, 1)
    front = (front[0] + [-0.15, 0, 0], front[1])
    rear = plate_mesh(0.6, 0.3, 1)
    rear = (rear[0] + [0, 0, -0.2], rear[1])
    w = 0.3 - xs
    lit = plate_mesh(w, 0.3, 1)
    lit = (lit[0] + [xs + w / 2, 0, -0.2], lit[1])
    tx = monostatic_xz([th])
    ref = po_scattered_field(*_cat(front, lit), "pec", tx, tx, FREQS)
    got = po_scattered_field(*_cat(front, rear), "pec", tx, tx, FREQS, shadow_refine_m=0.005)
    assert np.abs(db(np.abs(got) ** 2 / np.abs(ref) ** 2)).max() < 0.3
    crude = po_scattered_field(*_cat(front, rear), "pec", tx, tx, FREQS, shadow_refine_m=0, max_facet_edge_m=0)
    assert np.abs(db(np.abs(crude) ** 2 / np.abs(ref) ** 2)).max() > 3.0  # why the refinement exists


def test_splitting_facets_keeps_the_far_field_exact():
    v, f = plate_mesh(0.5, 0.5, 1)
    tx = monostatic_xz(np.radians([0.0, 4.0, 11.0]))
    a = po_scattered_field(v, f, "pec", tx, tx, FREQS, max_facet_edge_m=0)
    b = po_scattered_field(v, f, "pec", tx, tx, FREQS, max_facet_edge_m=0.03)
    np.testing.assert_allclose(a, b, rtol=1e-9, atol=1e-12)


def test_amplitude_weight():
    v, f = plate_mesh(0.3, 0.3, 1)
    tx = 3.0 * np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0]])
    a = po_scattered_field(v, f, "pec", tx, tx, FREQS, near_field=True)
    seen = {}

    def weight(m, u_tx, u_rx):
        seen["u"] = (m, u_tx, u_rx)
        return np.full(len(m), 2.0)

    b = po_scattered_field(v, f, "pec", tx, tx, FREQS, near_field=True, amplitude_weight=weight)
    np.testing.assert_allclose(b, 2.0 * a, rtol=1e-12)
    m, u_tx, u_rx = seen["u"]
    np.testing.assert_allclose(np.linalg.norm(u_tx, axis=1), 1.0)
    assert np.all(u_tx[:, 2] < 0) and np.all(u_rx[:, 2] < 0)  # from the antennas down to the plate


def test_scene_glue_h_target():
    from rfir_stages.po import scene_mesh, scene_rcs
    from rfir_stages.simulate.scenes import build_scene

    spec = build_scene("h-target")
    v, f, mats, th = scene_mesh(spec)
    assert len(f) == spec.num_faces and set(mats) == {"metal"} and np.all(th > 0)
    az = np.radians([0.0, 90.0])
    tx = 2.0 * np.stack([np.cos(az), np.sin(az), np.zeros(2)], 1)
    s = scene_rcs(spec, tx, tx, FREQS, near_field=True)
    assert s.shape == (2, 2) and np.all(np.isfinite(s))
    # broadside on the 0.5 x 0.6 m face pair (y normal): strong specular return
    assert 10 * np.log10(np.abs(s[1, 0]) ** 2) > 0.0


def test_slab_thickness_per_face_matches_fresnel_helper():
    """Per-face slab thickness (0 = half-space) gives |Gamma_slab|^2 x the PEC plate at broadside."""
    L = 0.3
    v, f = plate_mesh(L, L, 1)  # 2 facets: one slab, one half-space, same material
    tx = monostatic_xz([0.0])
    th = np.array([0.0075, 0.0])
    s = po_scattered_field(v, f, "plasterboard", tx, tx, FREQS, face_thickness=th)[0]
    pec = po_scattered_field(v, f, "pec", tx, tx, FREQS)[0]
    g_slab = itu_reflection_coefficient("plasterboard", FREQS, 1.0, "TE", thickness_m=0.0075)
    g_half = itu_reflection_coefficient("plasterboard", FREQS, 1.0, "TE")
    np.testing.assert_allclose(s, pec * -(g_slab + g_half) / 2.0, rtol=1e-9)


@pytest.mark.parametrize("pol,sign", [("V", 1.0), ("H", -1.0)])
def test_dihedral_double_bounce_phase_equals_equivalent_plate(pol, sign):
    """At the bisector a 90-degree PEC corner retro-reflects like a flat plate of area sqrt(2) a b
    through the fold line, with the same field for E across the fold (V here) and the opposite
    sign for E along the fold (H): two mirror images = a 180-degree rotation about the fold.
    Checks amplitude and phase of the second-order term against first-order PO of that plate."""
    a, b = 0.4, 0.25
    v, f = dihedral_mesh(a, b, 2)
    d = np.array([1.0, 0.0, 1.0]) / np.sqrt(2.0)
    tx = FAR * d[None, :]
    pv, pf = plate_mesh(np.sqrt(2.0) * b, a, 1)
    rot = np.stack([np.array([1.0, 0.0, -1.0]) / np.sqrt(2.0), np.array([0.0, 1.0, 0.0]), d], 1)
    pv = pv @ rot.T  # plate through the origin, normal d
    first = po_scattered_field(v, f, "pec", tx, tx, FREQS, polarization=pol)
    double = po_scattered_field(v, f, "pec", tx, tx, FREQS, polarization=pol, second_order=True) - first
    plate = po_scattered_field(pv, pf, "pec", tx, tx, FREQS, polarization=pol)
    np.testing.assert_allclose(double / plate, sign, atol=0.03)


def test_shadow_refinement_blocks_do_not_change_results(monkeypatch):
    import rfir_stages.po.solver as solver

    front = plate_mesh(0.3, 0.3, 3)
    front = (front[0] + [-0.15, 0, 0], front[1])
    rear = plate_mesh(0.6, 0.3, 4)
    rear = (rear[0] + [0, 0, -0.2], rear[1])
    v, f = _cat(front, rear)
    tx = monostatic_xz(np.radians([1.0, 2.0, 5.0]))
    a = po_scattered_field(v, f, "pec", tx, tx, FREQS, shadow_refine_m=0.004)
    monkeypatch.setattr(solver, "_REFINE_BLOCK", 50)
    b = po_scattered_field(v, f, "pec", tx, tx, FREQS, shadow_refine_m=0.004)
    np.testing.assert_allclose(a, b, rtol=1e-10, atol=1e-12)


def test_antenna_weight_helper():
    from rfir_stages.po import antenna_weight

    class Cosine:  # gain cos^2 about a boresight (duck-typed antenna)
        def __init__(self, bore):
            self.b = np.asarray(bore, float) / np.linalg.norm(bore)

        def gain(self, d):
            return np.clip(d @ self.b, 0, 1) ** 2

    v, f = plate_mesh(0.2, 0.2, 2)
    tx = 3.0 * np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    ants = [Cosine([0, 0, -1]), Cosine([1, 0, -1])]  # on the plate; 45 degrees off
    a = po_scattered_field(v, f, "pec", tx, tx, FREQS, near_field=True)
    b = po_scattered_field(v, f, "pec", tx, tx, FREQS, near_field=True, amplitude_weight=antenna_weight(ants))
    np.testing.assert_allclose(np.abs(b[0]), np.abs(a[0]), rtol=0.01)  # on boresight
    np.testing.assert_allclose(np.abs(b[1]) ** 2, np.abs(a[1]) ** 2 * 0.25, rtol=0.05)  # G_T G_R = (1/2)^2


def test_provenance_names_backend_and_settings():
    import json

    from rfir_stages.po import provenance

    p = provenance(second_order=True, near_field=True)
    assert p["backend"] == "po" and p["second_order"] is True and p["near_field"] is True
    assert p["polarization"] == "V" and p["shadow_samples"] == 4
    json.dumps(p)


def test_quasi_monostatic_2mm_equals_monostatic():
    """The simulator's radar has Tx and Rx 2 mm apart (a Sionna work-around): same answer as
    co-located within 0.01 dB for the first- and second-order terms."""
    v, f = dihedral_mesh(0.3, 0.2, 2)
    d = np.array([1.0, 0.0, 1.0]) / np.sqrt(2.0)
    pos = 2.0 * d[None, :]
    off = np.array([[0.0, 0.001, 0.0]])
    a = po_rcs(v, f, "metal", pos, pos, FREQS, near_field=True, second_order=True)
    b = po_rcs(v, f, "metal", pos + off, pos - off, FREQS, near_field=True, second_order=True)
    assert np.abs(db(b / a)).max() < 0.01
