"""A reduced room for the RSSI tests: 4 x 3 x 2.5 m, a partition wall with a doorway, one table.

Synthetic measurements come from an independent closed form (no rfir code): free-space Friis,
minus `wall_loss_db` when the Tx-Rx segment crosses the partition (outside the doorway), plus a
floor reflection (image source, coefficient `floor_gamma`) summed coherently.
"""
from __future__ import annotations

import math

import numpy as np

import torch

from rfir_core.artifacts import write_artifact
from rfir_stages.geom import gaussians_from_mesh, write_scene_artifact
from rfir_stages.model.artifact import physical_fields
from rfir_stages.model.occlusion import FrozenGeometry, make_provider
from rfir_stages.model.physical import MaterialValues, PairSettings
from rfir_stages.model.room_paths import build_patch_set, trace_room_paths
from rfir_stages.model.surfels import surfel_areas
from rfir_stages.simulate.scenes import _merge, box, rect_xy, wall

ROOM = (4.0, 3.0, 2.5)
PART_X = 2.0
DOOR = (1.8, 2.6, 0.0, 2.0)  # along y from 0: (u0, u1, z0, z1)
C0 = 299_792_458.0


def room_mesh():
    """(vertices, faces, face labels, label names)."""
    lx, ly, lz = ROOM
    parts = [
        ("floor", rect_xy(0, lx, 0, ly, 0.0, up=True)),
        ("ceiling", rect_xy(0, lx, 0, ly, lz, up=False)),
        ("wall_a", wall((0, 0, 0), (0, 1, 0), (1, 0, 0), ly, lz)),
        ("wall_b", wall((lx, 0, 0), (0, 1, 0), (-1, 0, 0), ly, lz)),
        ("wall_c", wall((0, 0, 0), (1, 0, 0), (0, 1, 0), lx, lz)),
        ("wall_d", wall((0, ly, 0), (1, 0, 0), (0, -1, 0), lx, lz)),
        ("partition", wall((PART_X, 0, 0), (0, 1, 0), (-1, 0, 0), ly, lz, [DOOR])),
        ("table_00", box((0.6, 0.6, 0.0), (1.4, 1.2, 0.7))),
    ]
    v, f = _merge([p for _, p in parts])
    labels = np.concatenate([np.full(len(p[1]), i) for i, (_, p) in enumerate(parts)])
    return v, f, labels, [n for n, _ in parts]


def scene_fields(spacing_m: float = 0.6) -> tuple[dict, list]:
    v, f, lab, names = room_mesh()
    return gaussians_from_mesh(v, f, spacing_m, labels=lab), names


def room_geometry(spacing_m: float = 0.3, occlusion: str = "auto"):
    """(RoomGeometry of the reduced room's surfels at spacing_m with default RoomSettings, labels [G] int64,
    label names)."""
    import torch

    from rfir_stages.model.room import RoomGeometry, RoomSettings
    from rfir_stages.model.occlusion import FrozenGeometry

    fields, names = scene_fields(spacing_m)
    t = lambda k: torch.as_tensor(np.asarray(fields[k], np.float64))  # noqa: E731
    geom = FrozenGeometry(t("gaussians/means"), t("gaussians/log_scales"), t("gaussians/rotations"),
                          t("gaussians/normals"))
    labels = np.asarray(fields["gaussians/labels"], np.int64)
    return RoomGeometry(geom, torch.as_tensor(labels), labels, RoomSettings(), occlusion=occlusion), labels, names


def write_scene(path, spacing_m: float = 0.6):
    fields, names = scene_fields(spacing_m)
    return write_scene_artifact(path, fields, label_names=names, spacing_m=spacing_m)


def crosses_partition(tx: np.ndarray, rx: np.ndarray) -> np.ndarray:
    """[M] bool: the segment crosses the plane x = PART_X outside the doorway."""
    t = (PART_X - tx[:, 0]) / np.where(rx[:, 0] != tx[:, 0], rx[:, 0] - tx[:, 0], 1e-12)
    p = tx + t[:, None] * (rx - tx)
    through = (t > 0) & (t < 1)
    in_door = (p[:, 1] > DOOR[0]) & (p[:, 1] < DOOR[1]) & (p[:, 2] < DOOR[3])
    return through & ~in_door


def reference_gain_db(tx, rx, freq_hz, wall_loss_db=8.0, floor_gamma=-0.4):
    """Independent closed form: Friis x wall loss + floor image reflection (coherent)."""
    lam = C0 / freq_hz
    k = 2 * math.pi / lam
    d = np.linalg.norm(rx - tx, axis=1)
    img = tx * np.array([1, 1, -1])
    d2 = np.linalg.norm(rx - img, axis=1)
    s = lam / (4 * math.pi * d) * np.exp(-1j * k * d) + floor_gamma * lam / (4 * math.pi * d2) * np.exp(-1j * k * d2)
    block = crosses_partition(tx, rx) | crosses_partition(img, rx)
    s = s * np.where(block, 10 ** (-wall_loss_db / 20), 1.0)
    return 20 * np.log10(np.abs(s))


def links(n_tx=(2, 2), n_rx=(6, 5), tx_z=2.0, rx_z=1.0):
    lx, ly, _ = ROOM
    tx = np.array([[x, y, tx_z] for x in np.linspace(0.7, lx - 0.7, n_tx[0]) for y in np.linspace(0.6, ly - 0.6, n_tx[1])])
    rx = np.array([[x, y, rx_z] for x in np.linspace(0.3, lx - 0.3, n_rx[0]) for y in np.linspace(0.3, ly - 0.3, n_rx[1])])
    tx_id = np.repeat(np.arange(len(tx)), len(rx))
    rx_id = np.tile(np.arange(len(rx)), len(tx))
    return tx, rx, tx_id, rx_id


def write_measurements(path, freq_hz=2.4e9, seed=0, tx_gain_db=None, rx_gain_db=None, simulated=True, **kw):
    """Measurements of `links(**kw)`; tx_gain_db [T] / rx_gain_db [R]: device gains added (dB); simulated:
    the file records a simulator (ideal devices), else none, as measured data."""
    tx, rx, tx_id, rx_id = links(**kw)
    t, r = tx[tx_id], rx[rx_id]
    gain = reference_gain_db(t, r, freq_hz)
    if tx_gain_db is not None:
        gain = gain + np.asarray(tx_gain_db)[tx_id]
    if rx_gain_db is not None:
        gain = gain + np.asarray(rx_gain_db)[rx_id]
    split = np.zeros(len(t), np.int64)
    split[np.random.default_rng(seed).permutation(len(t))[: len(t) // 5]] = 1
    data = {"tx_pos": t, "rx_pos": r, "freq_hz": np.array([freq_hz]), "path_gain_db": gain[:, None],
            "tx_id": tx_id, "rx_id": rx_id, "split": split,
            "scene_bounds": np.array([[0.0, 0.0, 0.0], list(ROOM)])}
    # the reference model's own levels: ideal devices, as rfir simulate's (rf-fit's device_gains = "auto")
    return write_artifact(path, "measurements", data, attrs={"task": "rssi", "scene": "testroom"},
                          free={"simulator": {"@attrs": {"simulator": "tests reference model"}}} if simulated else None)


def write_air_room(path, freq_hz: float = 2.4e9):
    """The room model (model_kind rssi_physical) of a 4 x 3 x 2.5 m room with a table, fitted at freq_hz, whose
    every material is air (eps_r 1, sigma 0, no diffuse share): it predicts free space."""
    parts = [rect_xy(0, 4, 0, 3, 0.0, up=True), rect_xy(0, 4, 0, 3, 2.5, up=False),
             wall((0, 0, 0), (0, 1, 0), (1, 0, 0), 3, 2.5), wall((4, 0, 0), (0, 1, 0), (-1, 0, 0), 3, 2.5),
             wall((0, 0, 0), (1, 0, 0), (0, 1, 0), 4, 2.5), wall((0, 3, 0), (1, 0, 0), (0, -1, 0), 4, 2.5),
             box((0.6, 0.6, 0.0), (1.4, 1.2, 0.7))]
    names = ["floor", "ceiling", "wall_a", "wall_b", "wall_c", "wall_d", "table"]
    v, f = _merge(parts)
    labels = np.concatenate([np.full(len(p[1]), i) for i, p in enumerate(parts)])
    fields = gaussians_from_mesh(v, f, 0.6, labels=labels)
    labels = np.asarray(fields["gaussians/labels"], np.int64)     # per Gaussian now
    t = lambda k: torch.as_tensor(np.asarray(fields[f"gaussians/{k}"], np.float64))  # noqa: E731
    n = len(names)
    air = MaterialValues(torch.ones(n), torch.zeros(n), 1.0, torch.zeros(n), torch.full((n,), 0.1))
    model, attrs = physical_fields(air, torch.as_tensor(labels), surfel_areas(t("means"), t("log_scales"),
                                   t("rotations"), t("normals")), np.array([freq_hz]), PairSettings(), names, 0.0)
    data = {k: v for k, v in fields.items() if k.startswith("gaussians/")}
    data.update(model)
    data["rf/freq_hz"] = np.array([freq_hz])
    attrs.update({"antenna_kind": "isotropic", "model_kind": "rssi_physical"})
    return write_artifact(path, "rf", data, attrs={"task": "rssi", "label_names": np.asarray(names, dtype=object)},
                          free={"model": {"@attrs": attrs}})


def metal_floor_paths(n_rx: int, freq_hz: float, max_order: int = 1):
    """(tx [n,3], rx [n,3], room paths, patch count) over a 30 x 30 m floor alone: Tx at 1.5 m, n_rx receivers at
    1 m from 1 to 10 m along x, traced at freq_hz with horizontal polarisation (the two-ray closed form's set-up)."""
    v = np.array([[-15.0, -15, 0], [15, -15, 0], [15, 15, 0], [-15, 15, 0]])
    g = gaussians_from_mesh(v, np.array([[0, 1, 2], [0, 2, 3]]), 1.0, labels=np.zeros(2, np.int64))
    t = lambda key: torch.as_tensor(np.asarray(g[key], np.float64))  # noqa: E731
    geom = FrozenGeometry(t("gaussians/means"), t("gaussians/log_scales"), t("gaussians/rotations"),
                          t("gaussians/normals"))
    areas = surfel_areas(geom.means, geom.log_scales, geom.rotations, geom.normals)
    patches = build_patch_set(geom, areas, torch.as_tensor(g["gaussians/labels"], dtype=torch.int64), coplanar_m=0.01,
                              extent="disks")
    x = np.linspace(1.0, 10.0, n_rx)
    tx = np.tile([[0.0, 0.0, 1.5]], (n_rx, 1))
    rx = np.stack([x, np.zeros_like(x), np.full_like(x, 1.0)], 1)
    paths = trace_room_paths(tx, rx, np.full(n_rx, freq_hz), patches, make_provider("auto", geom), polarisation="H",
                             max_order=max_order)
    return tx, rx, paths, patches.num
