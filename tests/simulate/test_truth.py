"""The simulator's true materials against the normal-incidence slab closed form."""
import cmath
import math

import numpy as np
import pytest

from rfir_core.physics.materials import C0, itu_law
from rfir_stages.simulate.truth import object_class, true_materials


def slab_reflection_normal(eps_r: float, sigma: float, freq_hz: float, d_m: float) -> float:
    """|Gamma| of a lossy slab in air at normal incidence: Gamma_1 (1 - e^{-2j delta}) / (1 - Gamma_1^2 e^{-2j delta}),
    Gamma_1 = (1 - n) / (1 + n), n = sqrt(eps_r - j sigma / (omega eps_0)), delta = k_0 n d (written out here)."""
    omega = 2 * math.pi * freq_hz
    n = cmath.sqrt(eps_r - 1j * sigma / (omega * 8.8541878128e-12))
    g1 = (1 - n) / (1 + n)
    ph = cmath.exp(-2j * (omega / C0) * n * d_m)
    return abs(g1 * (1 - ph) / (1 - g1 * g1 * ph))


@pytest.mark.parametrize("freq_hz", [2.4e9, 5.8e9])
def test_trio_truth_matches_slab_closed_form(freq_hz):
    truth = true_materials("trio", ["dihedral", "block", "pane"], freq_hz)
    assert set(truth) == {"dihedral", "block", "pane"}
    assert truth["dihedral"][0] == "metal" and truth["dihedral"][4] > 0.99
    for name, itu in (("block", "wood"), ("pane", "glass")):
        got_itu, th, eps, sig, g = truth[name]
        assert got_itu == itu
        e_ref, s_ref = (float(np.asarray(x).reshape(-1)[0]) for x in itu_law(itu, freq_hz))
        assert (eps, sig) == pytest.approx((e_ref, s_ref))
        assert g == pytest.approx(slab_reflection_normal(eps, sig, freq_hz, th), abs=1e-6)
    # a thin glass pane reflects more at 5.8 than at 2.4 GHz (its electrical thickness grows)
    if freq_hz == 5.8e9:
        assert truth["pane"][4] > true_materials("trio", ["pane"], 2.4e9)["pane"][4] + 0.05


def test_object_class_strips_number_suffix():
    assert object_class("desk_03") == "desk" and object_class("wall_back") == "wall_back"


def test_truth_follows_the_simulators_scene_edits():
    """A scene simulated with `wall_back:material:metal` has a metal back wall; the other walls stay concrete,
    and the edits are read back from a measurements artifact's simulator attributes."""
    from types import SimpleNamespace

    from rfir_stages.simulate.scene_edits import measurement_scene_edits

    plain = true_materials("classroom", ["wall_back", "wall_front"], 2.4e9)
    meas = SimpleNamespace(free={"simulator@attrs": {"scene_edits": "wall_back:material:metal; desk_0[0369]:delete"}})
    edits = measurement_scene_edits(meas)
    assert edits == ["wall_back:material:metal", "desk_0[0369]:delete"]
    edited = true_materials("classroom", ["wall_back", "wall_front"], 2.4e9, edits)
    assert plain["wall_back"][0] == "concrete" and edited["wall_back"][0] == "metal" and edited["wall_back"][4] > 0.99
    assert edited["wall_front"] == plain["wall_front"]
    assert measurement_scene_edits(SimpleNamespace(free={})) == []
