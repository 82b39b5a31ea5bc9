"""Antenna patterns shared by the simulator and the fitter (pure numpy, no Sionna).

Gains are power gains relative to isotropic (linear), functions of the angle `theta_rad`
between the propagation direction and the antenna's boresight. Field patterns are sqrt(gain).

Horn (RCS task): an analytic cos^q pattern over the front hemisphere, zero behind,
    G(theta) = G0 cos(theta)^q   for theta < 90 deg,     G0 = 2 (q + 1),
normalised so that the gain integrates to 4 pi over the sphere. q is chosen from the half-power
beamwidth: cos(HPBW / 2)^q = 1/2. The default HPBW of 40 deg gives q = 11.14 and
G0 = 24.3 (13.9 dBi), a typical standard-gain horn. The pattern is rotationally symmetric
(same in the E and H planes) and co-polarised (vertical): Sionna is run with isotropic
V-polarised antennas and each path's amplitude is multiplied by sqrt(G_T(theta_t) G_R(theta_r)).

Omni (RSSI task): G = 1 in every direction (Sionna's isotropic V-polarised antenna).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

DEFAULT_HORN_HPBW_DEG = 40.0


def boresight_split(text: str) -> tuple[str, str]:
    """(an antenna text without its boresight, the boresight text or ""): "horn:60@0,1,0" -> ("horn:60", "0,1,0").
    A horn's or a table's boresight is stated after the last "@" (docs/artifacts.md); other kinds have none."""
    head, at, tail = text.rpartition("@")
    return (head, tail) if at and head.split(":")[0] in ("horn", "table") else (text, "")


def horn_exponent(hpbw_deg: float = DEFAULT_HORN_HPBW_DEG) -> float:
    """The exponent q of cos^q with the given half-power (-3.01 dB) beamwidth."""
    if not 0.0 < hpbw_deg < 180.0:
        raise ValueError(f"horn beamwidth must be in (0, 180) degrees, got {hpbw_deg}")
    return math.log(0.5) / math.log(math.cos(math.radians(hpbw_deg) / 2.0))


def horn_boresight_gain(hpbw_deg: float = DEFAULT_HORN_HPBW_DEG) -> float:
    """G0 = 2 (q + 1), linear."""
    return 2.0 * (horn_exponent(hpbw_deg) + 1.0)


def horn_gain(theta_rad, hpbw_deg: float = DEFAULT_HORN_HPBW_DEG) -> np.ndarray:
    """Linear power gain of the cos^q horn at angle theta_rad off boresight (0 behind)."""
    q = horn_exponent(hpbw_deg)
    c = np.cos(np.asarray(theta_rad, dtype=np.float64))
    return np.where(c > 0.0, horn_boresight_gain(hpbw_deg) * np.clip(c, 0.0, 1.0) ** q, 0.0)


def omni_gain(theta_rad) -> np.ndarray:
    """Isotropic: 1 everywhere."""
    return np.ones_like(np.asarray(theta_rad, dtype=np.float64))


@dataclass(frozen=True)
class Antenna:
    """An antenna: kind "horn" or "omni", boresight (unit vector, world) and horn beamwidth."""

    kind: str = "omni"
    boresight: tuple = (1.0, 0.0, 0.0)
    hpbw_deg: float = DEFAULT_HORN_HPBW_DEG

    def gain(self, directions) -> np.ndarray:
        """Linear gain toward unit direction vectors (..., 3) leaving the antenna."""
        d = np.asarray(directions, dtype=np.float64)
        if self.kind == "omni":
            return np.ones(d.shape[:-1])
        if self.kind != "horn":
            raise ValueError(f"unknown antenna kind {self.kind!r} (known: horn, omni)")
        b = np.asarray(self.boresight, dtype=np.float64)
        b = b / np.linalg.norm(b)
        cos_t = np.clip((d @ b) / np.maximum(np.linalg.norm(d, axis=-1), 1e-30), -1.0, 1.0)
        return horn_gain(np.arccos(cos_t), self.hpbw_deg)

    @property
    def boresight_gain(self) -> float:
        return 1.0 if self.kind == "omni" else horn_boresight_gain(self.hpbw_deg)


def unit_from_theta_phi(theta_rad, phi_rad) -> np.ndarray:
    """Sionna's spherical angles (theta from +z, phi from +x) to unit vectors (..., 3)."""
    theta = np.asarray(theta_rad, dtype=np.float64)
    phi = np.asarray(phi_rad, dtype=np.float64)
    st = np.sin(theta)
    return np.stack([st * np.cos(phi), st * np.sin(phi), np.cos(theta)], axis=-1)
