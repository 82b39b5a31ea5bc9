"""Full-wave reference for the PO backend: boundary-element (EFIE, RWG) monostatic RCS of perfect
conductors with bempp-cl, and the Mie series of a PEC sphere. Optional extra `rfir[fullwave]`.

Public API:
- `mie_pec_sphere_rcs(radius_m, freq_hz)` -> monostatic sigma [m^2] (closed-form series; no bempp needed);
- `bem_monostatic_rcs(vertices, faces, freq_hz, directions, polarization)` -> (M,) complex amplitude s [m],
  sigma = |s|^2, same normalisation as `rfir_stages.po.po_scattered_field` in far-field mode;
- `plate_screen`, `dihedral_screen`: the PO test meshes as conforming screens for the BEM.
"""
from .mie import mie_pec_sphere_rcs

__all__ = ["bem_monostatic_rcs", "dihedral_screen", "merge_vertices", "mie_pec_sphere_rcs", "plate_screen"]


def __getattr__(name):  # bempp-cl (optional) and the PO meshes are imported only when used
    if name == "bem_monostatic_rcs":
        from .bem import bem_monostatic_rcs
        return bem_monostatic_rcs
    if name in ("dihedral_screen", "merge_vertices", "plate_screen"):
        from . import meshes
        return getattr(meshes, name)
    raise AttributeError(name)
