"""Comparing a calibration with ground-truth cameras (for tests and the accuracy figures in docs)."""
from __future__ import annotations

from pathlib import Path

import numpy as np


def rotation_angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    """Angles (deg) of the relative rotations Ra^T Rb, batched over the leading axis."""
    rel = np.einsum("...ji,...jk->...ik", Ra, Rb)
    cos = (np.trace(rel, axis1=-2, axis2=-1) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def pose_errors(calib, cameras) -> dict:
    """Centre (m) and rotation (deg) errors of a `calib` artifact against a `cameras` artifact,
    matched by image file name; plus the registered fraction of the ground-truth images."""
    truth = {str(n): p for n, p in zip(cameras.data["image_names"], cameras.data["world_from_camera"])}
    names = [Path(str(p)).name for p in calib.data["image_paths"]]
    est = np.asarray(calib.data["world_from_camera"])
    gt = np.stack([truth[n] for n in names])
    centre = np.linalg.norm(est[:, :3, 3] - gt[:, :3, 3], axis=1)
    rot = rotation_angle_deg(gt[:, :3, :3], est[:, :3, :3])
    return {"registered_fraction": len(names) / len(truth),
            "centre_error_mean_m": float(centre.mean()), "centre_error_max_m": float(centre.max()),
            "rotation_error_mean_deg": float(rot.mean()), "rotation_error_max_deg": float(rot.max())}
