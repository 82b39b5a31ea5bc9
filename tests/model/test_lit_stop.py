"""Tracing the lit state with the early stop at the lit threshold (occlusion.lit_stop) gives the same
lit and shadowed surfels as tracing every ray to t_stop 1e-4."""
import numpy as np
import torch

from rfir_stages.model.physical import lit_state
from rfir_stages.model.occlusion import lit_stop, make_provider

from .helpers import plate_mesh, surfels

THRESHOLD = 0.2


def _box():
    """Surfels of a closed 0.3 x 0.2 x 0.25 m box centred at the origin (3 cm spacing)."""
    size = np.array([0.3, 0.2, 0.25])
    verts, faces = [], []
    for axis in range(3):
        u, w = np.eye(3)[(axis + 1) % 3], np.eye(3)[(axis + 2) % 3]
        for sign in (-1.0, 1.0):
            v, f = plate_mesh(sign * size[axis] / 2 * np.eye(3)[axis], u, w, size[(axis + 1) % 3], size[(axis + 2) % 3])
            faces.append(f + 4 * len(verts))
            verts.append(v)
    return surfels(np.concatenate(verts), np.concatenate(faces), 0.03)[0]


def test_lit_stop_keeps_every_lit_state_and_stops_shadowed_rays_early():
    geom = _box()
    provider = make_provider("tracer", geom)
    rng = np.random.default_rng(0)
    d = rng.normal(size=(12, 3))
    antennas = torch.as_tensor(d / np.linalg.norm(d, axis=1, keepdims=True) * 3.0)
    origins = antennas.repeat_interleave(geom.num, 0)
    targets = torch.arange(geom.num).repeat(len(antennas))
    op = torch.full((geom.num,), 0.9, dtype=torch.float64)
    full = provider.segment_transmittance(origins, targets, 0.0025, op, 1e-4)
    early = provider.segment_transmittance(origins, targets, 0.0025, op, lit_stop(1e-4, THRESHOLD))
    lit = lit_state(full, THRESHOLD)
    assert 0.2 < float(lit.mean()) < 0.8                        # both lit and shadowed surfels are asked
    assert torch.equal(lit_state(early, THRESHOLD), lit)
    assert torch.equal(early[lit > 0], full[lit > 0])            # lit rays are traced to the end as before
    assert bool((early[lit == 0] > full[lit == 0]).any())        # shadowed ones stopped sooner
    assert lit_stop(1e-4, 0.0) == 1e-4                           # soft shadows: the transmittance itself
