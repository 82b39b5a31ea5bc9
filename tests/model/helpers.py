"""Small geometry builders for the physical-model tests: surfels on plates, monostatic links."""
import math

import numpy as np
import torch

from rfir_stages.geom.from_mesh import gaussians_from_mesh
from rfir_stages.model.antenna_patterns import AntennaPattern
from rfir_stages.model.links import make_links
from rfir_stages.model.occlusion import FrozenGeometry

ISO = AntennaPattern("isotropic")


def plate_mesh(centre, u, w, a, b):
    """A rectangle a (along u) x b (along w) centred at `centre`: vertices [4, 3], faces [2, 3]."""
    c, u, w = (np.asarray(x, float) for x in (centre, u, w))
    v = np.array([c - a / 2 * u - b / 2 * w, c + a / 2 * u - b / 2 * w, c + a / 2 * u + b / 2 * w,
                  c - a / 2 * u + b / 2 * w])
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def surfels(vertices, faces, spacing_m, labels=None, rectangles=False):
    g = gaussians_from_mesh(vertices, faces, spacing_m, labels=labels, rectangles=rectangles)
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


def double_bounce_error_db(verts, faces, aspects_deg, freq_hz, spacing_m=0.03, range_m=3.0, sbr_spacing_m=None):
    """[A] dB: the model's second order (perfect conductor, surfels at spacing_m; its field with and without
    the double bounce subtracted) minus the PO solver's (second order on and off subtracted) on the same mesh,
    monostatic at range_m; asserts the model has double-bounce items."""
    from rfir_stages.model.physical import MaterialParams, PairSettings, build_pairs, scattered_field
    from rfir_stages.po import po_scattered_field
    from rfir_stages.model.occlusion import make_provider

    geom, _ = surfels(verts, faces, spacing_m)
    pos, links = monostatic(aspects_deg, range_m, freq_hz)
    pairs = build_pairs(geom, links, ISO, ISO, make_provider("auto", geom), PairSettings())
    assert pairs.double is not None and pairs.double.num > 0
    mats = MaterialParams(1, eps_r=1.0, sigma_1ghz=1e7, scattering=1e-9, thickness_m=None).values()
    idx = torch.zeros(geom.num, dtype=torch.int64)
    with torch.no_grad():
        both, _ = scattered_field(pairs, idx, mats)
        pairs.double = None
        first, _ = scattered_field(pairs, idx, mats)
    ours = 20 * np.log10(np.abs((both - first)[:, 0].numpy()))
    kw = dict(near_field=True, ref_point=(0.0, 0.0, 0.0))
    if sbr_spacing_m is not None:
        kw["sbr_spacing_m"] = sbr_spacing_m
    s2 = po_scattered_field(verts, faces, "pec", pos, pos, [freq_hz], second_order=True, **kw) \
        - po_scattered_field(verts, faces, "pec", pos, pos, [freq_hz], second_order=False, **kw)
    lam = 299_792_458.0 / freq_hz
    po = 20 * np.log10(np.abs(s2[:, 0]) * lam / ((4 * math.pi) ** 1.5 * range_m**2))   # channel_from_amplitude
    return ours - po
