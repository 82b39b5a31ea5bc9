"""Small geometry builders for the physical-model tests: surfels on plates, monostatic links."""
import math

import numpy as np
import torch

from rfir_stages.geom.from_mesh import gaussians_from_mesh
from rfir_stages.rf_fit.antennas import AntennaPattern
from rfir_stages.rf_fit.links import make_links
from rfir_stages.rf_fit.occlusion import FrozenGeometry

ISO = AntennaPattern("isotropic")


def plate_mesh(centre, u, w, a, b):
    """A rectangle a (along u) x b (along w) centred at `centre`: vertices [4, 3], faces [2, 3]."""
    c, u, w = (np.asarray(x, float) for x in (centre, u, w))
    v = np.array([c - a / 2 * u - b / 2 * w, c + a / 2 * u - b / 2 * w, c + a / 2 * u + b / 2 * w,
                  c - a / 2 * u + b / 2 * w])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def surfels(vertices, faces, spacing_m, labels=None):
    g = gaussians_from_mesh(vertices, faces, spacing_m, labels=labels)
    geom = FrozenGeometry(*(torch.as_tensor(g["gaussians/" + k]).double()
                            for k in ("means", "log_scales", "rotations", "normals")))
    return geom, g


def monostatic(aspects_deg, range_m, freqs_hz, elevation_m=0.0):
    """Radar links on a horizontal circle around the origin (Tx = Rx), aspect 0 along +x."""
    a = np.radians(np.asarray(aspects_deg, float))
    pos = np.stack([range_m * np.cos(a), range_m * np.sin(a), np.full_like(a, elevation_m)], 1)
    return pos, make_links(pos, pos, np.atleast_1d(freqs_hz), torch.zeros(3, dtype=torch.float64), "rcs")


def rcs_dbsm(path_gain, range_m, freq_hz):
    lam = 299_792_458.0 / freq_hz
    return 10 * np.log10((4 * math.pi) ** 3 * range_m**4 * np.asarray(path_gain) / lam**2)
