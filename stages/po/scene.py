"""Glue between rfir scene specs (stages/simulate/scenes.py) and the PO solver.

Kept free of Sionna imports: a SceneSpec is duck-typed (objects with vertices, faces,
radio_material, thickness_m).
"""
from __future__ import annotations

import numpy as np

from .solver import po_scattered_field


def scene_mesh(spec) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """All objects of a SceneSpec as one mesh: vertices (V,3), faces (F,3), per-face ITU material
    names (F,) and per-face slab thickness (F,) in m (the same values Sionna gets)."""
    vs, fs, mats, ths, off = [], [], [], [], 0
    for o in spec.objects:
        v = np.asarray(o.vertices, float)
        f = np.asarray(o.faces, np.int64)
        vs.append(v)
        fs.append(f + off)
        mats.append(np.full(len(f), str(o.radio_material), dtype=object))
        ths.append(np.full(len(f), float(getattr(o, "thickness_m", 0.0))))
        off += len(v)
    if not vs:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, dtype=object), np.zeros(0)
    return np.concatenate(vs), np.concatenate(fs), np.concatenate(mats).astype(str), np.concatenate(ths)


def scene_rcs(spec, tx_pos, rx_pos, freqs_hz, *, use_thickness: bool = True, **kwargs) -> np.ndarray:
    """po_scattered_field on a whole SceneSpec with its per-object ITU materials (and slab
    thicknesses unless use_thickness=False). Returns the complex amplitude s (M, K)."""

    v, f, mats, th = scene_mesh(spec)
    return po_scattered_field(v, f, mats, tx_pos, rx_pos, freqs_hz,
                              face_thickness=th if use_thickness else None, **kwargs)


def antenna_weight(tx_antennas, rx_antennas=None):
    """An `amplitude_weight` for po_scattered_field from per-aspect antenna objects.

    tx_antennas / rx_antennas: sequences (one per aspect row of tx_pos / rx_pos) of objects with
    `.gain(unit_directions (N,3)) -> (N,)` linear power gain toward directions leaving the antenna
    (e.g. rfir_core.physics.antennas.Antenna). rx_antennas None = the same antennas (monostatic
    radar). Each facet's contribution is multiplied by sqrt(G_T(u_tx) G_R(u_rx)).
    """
    rx_antennas = tx_antennas if rx_antennas is None else rx_antennas

    def weight(m, u_tx, u_rx):
        out = np.empty(len(m))
        for mm in np.unique(m):
            sel = m == mm
            out[sel] = np.sqrt(np.asarray(tx_antennas[mm].gain(u_tx[sel])) * np.asarray(rx_antennas[mm].gain(u_rx[sel])))
        return out

    return weight
