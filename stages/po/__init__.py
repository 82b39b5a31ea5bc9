"""Coherent physical-optics (PO) RCS solver: `rfir simulate --rcs-backend po` and tests call it.

Public API:
- `po_scattered_field(vertices, faces, face_reflection, tx_pos, rx_pos, freqs_hz, ...)` -> (M, K)
  complex amplitude s [m] with sigma = |s|^2 (normalisation in `solver`'s docstring, docs/po.md);
- `po_rcs(...)` -> (M, K) sigma [m^2];
- `channel_from_amplitude(s, freqs_hz, R_t, R_r)` -> isotropic channel h (|h|^2 = P_R / P_T);
- `itu_reflection_coefficient(material, freq_hz, cos_theta, "TE"|"TM", thickness_m)` and
  `relative_permittivity(material, freq_hz)` (ITU-R P.2040 table + "pec" + "plastic");
- `scene_mesh(spec)`: vertices, faces, per-face material names and thicknesses of a SceneSpec;
  `scene_rcs(spec, ...)` runs the solver on it; `antenna_weight(antennas)` applies horn patterns;
- meshes with closed forms: `plate_mesh`, `dihedral_mesh`, `trihedral_mesh`, `icosphere`.
"""
from .currents import po_coefficients
from .geometry import dihedral_mesh, icosphere, plate_mesh, triangle_phase_factor, trihedral_mesh
from .facet_materials import (ITU_MATERIALS, face_reflection_from_materials, fresnel, itu_reflection_coefficient,
                        known_materials, relative_permittivity)
from .scene import antenna_weight, scene_mesh, scene_rcs
from .solver import channel_from_amplitude, po_rcs, po_scattered_field, provenance, rcs_dbsm
from .visibility import Occluder

BACKEND_NAME = "po"
__all__ = ["BACKEND_NAME", "ITU_MATERIALS", "Occluder", "antenna_weight", "channel_from_amplitude", "dihedral_mesh",
           "face_reflection_from_materials", "fresnel", "icosphere", "itu_reflection_coefficient", "known_materials",
           "plate_mesh", "po_coefficients", "po_rcs", "po_scattered_field", "provenance", "rcs_dbsm",
           "relative_permittivity", "scene_mesh", "scene_rcs", "triangle_phase_factor", "trihedral_mesh"]
