"""Whether the surfels sample the physical-optics integral finely enough at a frequency.

Each surfel stands for a rectangle cell (surfels.footprint_cells, docs/physics.md section 8.6); the
cells approximate the mesh's sub-triangles, and the error of that approximation grows with k times
the cell's size: against physical-optics data with the true materials and nothing fitted, cells
longer than about a quarter wavelength leave errors that finer surfels remove.
A fit or a prediction at a frequency where most of the surface lies in cells longer than
MAX_CELL_WAVELENGTHS says so, with the spacing that would do.
"""
from __future__ import annotations

import numpy as np
import torch

from rfir_core.physics.materials import C0
from .surfels import footprint_cells

MAX_CELL_WAVELENGTHS = 0.25   # long side of the cells, in wavelengths, above which lobes and levels drift
SURFACE_SHARE = 0.9           # the cell size that this share of the surface (by area) does not exceed
SPACING_PER_CELL = 1.4        # mesh-gaussians' --spacing over the cells' long side it gives (3 cm -> 2.1 cm)


def cell_size_m(log_scales: torch.Tensor, rotations: torch.Tensor, normals: torch.Tensor,
                areas_m2: torch.Tensor) -> float:
    """The long side [m] of the cells that SURFACE_SHARE of the surface area lies in cells shorter than
    (inputs [G, 3], [G, 4] wxyz, [G, 3], [G] m^2)."""
    with torch.no_grad():
        cells = footprint_cells(log_scales.double(), rotations.double(), normals.double(), areas_m2.double())
    side = (2.0 * cells.norm(dim=-1).max(-1).values).numpy()
    weight = areas_m2.double().numpy()
    if side.size == 0 or not weight.sum() > 0:
        return 0.0
    order = np.argsort(side)
    cum = np.cumsum(weight[order])
    return float(side[order][min(np.searchsorted(cum, SURFACE_SHARE * cum[-1]), side.size - 1)])


def coarse_surfels_warning(cell_m: float, freqs_hz) -> str | None:
    """A one-line warning when the cells (cell_size_m) are long against the shortest wavelength of
    freqs_hz [K] Hz, else None."""
    f_max = float(np.max(np.asarray(freqs_hz, float))) if np.size(freqs_hz) else 0.0
    if not f_max > 0 or not cell_m > 0:
        return None
    wavelength = C0 / f_max
    if cell_m <= MAX_CELL_WAVELENGTHS * wavelength:
        return None
    spacing = SPACING_PER_CELL * MAX_CELL_WAVELENGTHS * wavelength
    return (f"the surfels' cells ({cell_m * 100:.1f} cm long) exceed {MAX_CELL_WAVELENGTHS:g} wavelengths at "
            f"{f_max / 1e9:g} GHz ({wavelength * 100:.1f} cm): the physical optics of the surface is sampled too "
            f"coarsely there (expect dB-level errors); tile the mesh finer, `rfir mesh-gaussians --spacing "
            f"{spacing:.3f}` or less (docs/guide/rcs-sweep.md)")
