"""The simulator's true materials of a scene, for reports that compare fitted materials with them.

`true_materials(scene, names, freq_hz, scene_edits)` gives each object class's ITU-R P.2040 material, slab
thickness, eps_r and sigma at the frequency, and |Gamma(0)|: the normal-incidence reflection of
that slab (materials.normal_incidence_reflection, docs/physics.md sections 8.3-8.4), which is what
rf-fit reports for a fitted material. An object class is the object name without a trailing
"_<number>" (desk_03 and desk_07 are "desk"). `scene_edits` are the simulator's edits of the scene
(`simulate.scene_edits`, read back from a measurements file by
`scene_edits.measurement_scene_edits`): a scene simulated
with `wall_back:material:metal` has a metal back wall.
"""
from __future__ import annotations

import math
import re

import numpy as np
import torch

from rfir_core.physics.materials import C0, itu_law, normal_incidence_reflection, permittivity


def object_class(name: str) -> str:
    """desk_03 -> desk; names without a numbered suffix are their own class."""
    return re.sub(r"_\d+$", "", name)


def true_materials(scene_name: str, names: list[str], freq_hz: float, scene_edits: list[str] = ()) -> dict:
    """{class name: (ITU name, thickness m, eps_r, sigma S/m at freq_hz, |Gamma(0)|)} for the classes in
    `names` of the simulator's scene `scene_name` after `scene_edits` (the first object of each class)."""
    from rfir_stages.simulate import build_scene
    from rfir_stages.simulate.scene_edits import apply_scene_edits

    out = {}
    for obj in apply_scene_edits(build_scene(scene_name), list(scene_edits)).objects:
        cls = object_class(obj.name)
        if cls not in names or cls in out:
            continue
        eps, sig = (float(np.asarray(x).reshape(-1)[0]) for x in itu_law(obj.radio_material, freq_hz))
        eta = permittivity(torch.tensor(eps), torch.tensor(sig), torch.tensor(freq_hz))
        g = normal_incidence_reflection(eta, 2 * math.pi * freq_hz / C0, torch.tensor(obj.thickness_m))
        out[cls] = (obj.radio_material, obj.thickness_m, eps, sig, float(abs(g)))
    return out
