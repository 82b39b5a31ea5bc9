"""Small scenes and links for the rf-fit tests (fast: a few hundred Gaussians)."""
from __future__ import annotations

import math

import numpy as np
import torch

from rfir_core.artifacts import write_artifact
from rfir_stages.geom import gaussians_from_mesh
from rfir_core.physics.materials import C0
from rfir_stages.po import channel_from_amplitude, po_scattered_field
from rfir_stages.model.links import radar_links
from rfir_stages.model.occlusion import FrozenGeometry
from rfir_stages.model.link_set import LinkSet
from rfir_stages.simulate.scenes import box


def square(size_m: float, x_m: float = 0.0):
    """A square in the plane x = x_m, normal +x, centred on the x axis: (vertices, faces)."""
    h = size_m / 2
    v = np.array([[x_m, -h, -h], [x_m, h, -h], [x_m, h, h], [x_m, -h, h]], dtype=np.float64)
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def geometry(fields: dict) -> FrozenGeometry:
    t = lambda k: torch.as_tensor(fields[f"gaussians/{k}"], dtype=torch.float64)  # noqa: E731
    return FrozenGeometry(t("means"), t("log_scales"), t("rotations"), t("normals"))


def box_fields(half_m: float = 0.05, spacing_m: float = 0.03) -> dict:
    v, f = box((-half_m,) * 3, (half_m,) * 3)
    return gaussians_from_mesh(v, f, spacing_m)


def radar(aspects_rad, range_m: float, freqs_hz, height_m: float = 0.0, separation_m: float = 0.002) -> LinkSet:
    """Monostatic links around the origin (simulate's convention), antenna axes at the origin."""
    a = torch.as_tensor(np.asarray(aspects_rad, dtype=np.float64))
    pos = torch.stack([range_m * torch.cos(-a), range_m * torch.sin(-a), torch.full_like(a, height_m)], -1)
    off = torch.tensor([0.0, 0.0, separation_m / 2])
    axis = -torch.nn.functional.normalize(pos, dim=-1)
    return LinkSet(pos + off, pos - off, torch.as_tensor(np.asarray(freqs_hz, dtype=np.float64)), axis, axis)


def bistatic(tx, rx, freqs_hz) -> LinkSet:
    tx = torch.as_tensor(np.asarray(tx, dtype=np.float64))
    rx = torch.as_tensor(np.asarray(rx, dtype=np.float64))
    z = torch.zeros_like(tx)
    z[:, 2] = 1.0
    return LinkSet(tx, rx, torch.as_tensor(np.asarray(freqs_hz, dtype=np.float64)), z, z)


def db(s: torch.Tensor) -> np.ndarray:
    return 10 * np.log10(np.abs(s.detach().numpy()) ** 2 + 1e-300)


DEG = math.pi / 180


def po_measurements(path, verts, faces, names, thickness, freqs, aspects_deg, *, ranges=(3.0,), shift=0.0,
                    split=None):
    """Monostatic RCS of a mesh from the physical-optics solver (isotropic antennas), turntable convention
    at `ranges` m; split: per row (default: odd aspects test); shift [m]: every antenna moved by it."""
    centre = 0.5 * (verts.min(0) + verts.max(0))
    tx, rx, asp, rng = radar_links(np.asarray(aspects_deg) * DEG, np.asarray(ranges, float), centre)
    mid = 0.5 * (tx + rx)
    s = po_scattered_field(verts, faces, names, mid, mid, freqs, near_field=True, face_thickness=thickness,
                           ref_point=tuple(centre))
    r = np.linalg.norm(mid - centre, axis=1)
    pg = 20 * np.log10(np.abs(channel_from_amplitude(s, freqs, r, r)))
    lam = C0 / np.asarray(freqs)
    rcs = pg + 10 * np.log10((4 * math.pi) ** 3 * r[:, None] ** 4 / lam[None] ** 2)
    data = {"tx_pos": tx + shift, "rx_pos": rx + shift, "freq_hz": np.asarray(freqs, float), "path_gain_db": pg,
            "rcs_dbsm": rcs, "aspect_rad": asp, "range_m": rng,
            "split": np.asarray((np.arange(len(asp)) % 2) if split is None else split, dtype=np.int64),
            "scene_bounds": np.stack([verts.min(0), verts.max(0)]) + shift}
    write_artifact(path, "measurements", data, attrs={"task": "rcs", "scene": "test"})
    return path
