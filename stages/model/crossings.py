"""The objects and surfaces a Tx-Rx segment crosses, counted on a scene's Gaussians: what the multi-wall baseline
(rfir_stages.predict.rssi_baselines), the crossing effects of `rfir diagnose` and `rfir predict`'s crossing columns
read.

A segment's hits are those of rfir_core.physics.crossings.segment_hits (the one definition of what a leg meets:
more than LEG_MARGIN_M from either end). A crossing is then decided by the summed response of a group of hits,
never by one Gaussian: surfels tiled by rfir_stages.geom add up to ~2 on their surface and ~1 at its edge, while no
single one reaches 1 (the peak of a Gaussian lies off the ray almost surely), so `min_response` = 1 puts the
boundary on the surface's edge. With labels, the segment's hits are grouped by object, an object counts once when
its hits add up to >= min_response, and classes are the label names without their trailing number (desk_03 ->
desk, model.fit_physical.label_class_names). Without labels (geometry from photos), hits are grouped into surfaces
(`surface_groups`) and each surface whose hits add up to >= min_response counts once in one class "surface".
"""
from __future__ import annotations

import numpy as np

from rfir_core.physics.crossings import LEG_MARGIN_M, segment_hits

from .fit_physical import label_class_names


def surface_groups(query: np.ndarray, t_m: np.ndarray, normals: np.ndarray | None, response: np.ndarray,
                   merge_m: float = 0.1, min_cos: float = 0.8) -> np.ndarray:
    """[H] surface id of each hit (ids 0..S-1), hits given in any order.

    Along one ray, hits form a chain while each is less than `merge_m` behind the previous one;
    within a chain, hits whose normals agree with the strongest remaining hit's normal up to
    sign (|cos| >= min_cos, about 37 degrees) form one surface, and the rest are split the same
    way. Why these choices: a surface tiled by surfels is hit at one depth (its Gaussians are
    thin), and Gaussians fitted to photos spread a surface over a few centimetres; 0.1 m is
    about a wall's thickness, so the two faces of one wall (parallel normals of opposite sign)
    count once, while distinct walls and objects in a room stand further apart. Normals split
    what meets at one depth but is not one surface, such as the two walls at a corner. Hits
    with no normal (zero vector) join the surface of their chain's reference hit.
    """
    n = len(query)
    if n == 0:
        return np.zeros(0, dtype=np.int64)
    order = np.lexsort((t_m, query))
    q, t, r = query[order], t_m[order], response[order]
    if normals is None:
        nrm = np.zeros((n, 3))
    else:
        nrm = np.asarray(normals, dtype=np.float64)[order]
        length = np.linalg.norm(nrm, axis=1, keepdims=True)
        nrm = np.where(length > 1e-9, nrm / np.maximum(length, 1e-300), 0.0)
    unknown = ~np.any(nrm != 0, axis=1)
    new_chain = np.ones(n, dtype=bool)
    new_chain[1:] = (q[1:] != q[:-1]) | (np.diff(t) >= merge_m)
    chain = np.cumsum(new_chain) - 1
    surf = np.full(n, -1, dtype=np.int64)
    next_id = 0
    while (todo := np.flatnonzero(surf < 0)).size:
        c = chain[todo]
        # reference per chain: the strongest unassigned hit, preferring hits with a normal
        rank = np.lexsort((-r[todo], unknown[todo], c))
        ref = todo[rank][np.unique(c[rank], return_index=True)[1]]
        ref_of_chain = np.full(chain[-1] + 1, -1)
        ref_of_chain[chain[ref]] = ref
        new_id = np.full(chain[-1] + 1, -1)
        new_id[chain[ref]] = next_id + np.arange(len(ref))
        rn = ref_of_chain[c]
        agree = (np.abs((nrm[todo] * nrm[rn]).sum(1)) >= min_cos) | unknown[todo] | unknown[rn] | (todo == rn)
        surf[todo[agree]] = new_id[c[agree]]
        next_id += len(ref)
    out = np.empty(n, dtype=np.int64)
    out[order] = surf
    return out


def crossing_counts(provider, labels: np.ndarray | None, label_names, tx_m: np.ndarray, rx_m: np.ndarray,
                    min_response: float = 1.0, margin_m: float = LEG_MARGIN_M,
                    merge_m: float = 0.1) -> tuple[np.ndarray, list[str]]:
    """[M, C] crossings of each class by each segment tx_m -> rx_m [M, 3] m, and the class names.

    With labels: distinct objects crossed per class. Without: surfaces crossed, one class
    "surface"; surfaces come from `surface_groups` (merge_m) with the provider's normals when it
    has them (`provider.geom.normals`), else from depth alone.
    """
    q, g, t, resp = segment_hits(provider, tx_m, rx_m, margin_m)
    if labels is None or label_names is None or len(label_names) == 0:
        geom = getattr(provider, "geom", None)
        normals = None if geom is None or geom.normals is None else geom.normals.detach().double().numpy()[g]
        surf = surface_groups(q, t, normals, resp, merge_m=merge_m)
        total = np.bincount(surf, weights=resp, minlength=0)            # summed response per surface
        link = np.zeros(len(total), dtype=np.int64)
        link[surf] = q
        counts = np.bincount(link[total >= min_response], minlength=len(tx_m)).astype(float)[:, None]
        return counts, ["surface"]
    lab = np.asarray(labels)[g]
    ok = lab >= 0
    q, lab, resp = q[ok], lab[ok], resp[ok]
    names = label_class_names(label_names)
    classes = sorted(set(names))
    cls_of_label = np.array([classes.index(n) for n in names])
    total = np.zeros((len(tx_m), len(names)))
    np.add.at(total, (q, lab), resp)                           # summed response per (link, object)
    crossed = total >= min_response
    counts = np.zeros((len(tx_m), len(classes)))
    for c in range(len(classes)):
        counts[:, c] = crossed[:, cls_of_label == c].sum(1)
    return counts, classes
