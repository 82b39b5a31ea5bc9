"""Per-device gains of measured RSSI (docs/physics.md section 8.11): a fixed offset in dB per transmitter
and per receiver (antenna gain, cable loss, a radio's calibration), added to the physical path gain.

    P_dB(link) = P_physical_dB(link) + g_tx[tx(link)] + g_rx[rx(link)]

The gains are regularised by a zero-mean Gaussian prior of standard deviation `prior_db`: with
Gaussian dB errors of variance s^2 the negative log posterior per link is

    mean_links (pred - meas)^2 + (s^2 / prior_db^2) (1 / M) sum_devices g^2,

where s^2 is taken as the current mean squared residual (detached), so a device seen by few links
keeps a gain near 0 and a device the data never saw (an unseen receiver, a new transmitter of a
radio map) gets exactly 0, the prior mean.

Devices are told apart by the file's tx_id / rx_id where it has them (a receiver carried to many positions
is one device), else by position (rounded to 1 mm). A device with one position gets its gain wherever a
link starts or ends there; a side with one device (the one roaming receiver) gets its gain on every link.
Which sides get gains ("auto") is decided by validation on held-out positions (choose_device_gains).

The gains enter the dB prediction additively, so for fixed materials their optimum is closed form (ridge
regression: per device, the shrunk weighted mean of its links' residuals, DeviceGains.profile). A fit may
therefore profile them out at every step instead of moving them by gradient steps (fit_physical), and fit the
materials on a subsample of whole devices (whole_device_rows) while every device's final gain comes from all
its links (DeviceGains.fit_all).
"""
from __future__ import annotations

import numpy as np
import torch
from torch import nn

SIDES = ("tx", "rx")
CHOICES = ("off", "tx", "rx", "both")
KEY_DECIMALS = 3   # positions rounded to 1 mm identify a device


def _keys(points_m: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(points_m, dtype=np.float64).reshape(-1, 3), KEY_DECIMALS)


class DeviceGains(nn.Module):
    """Gains [D_side] dB of the distinct devices of each fitted side.

    Devices are those of the links tx_m, rx_m [M, 3] m (and ids [M]); `rows` [M_fit] int64 picks the links a fit
    evaluates (None: all M), so that a fit on a subsample still knows every device (one the subsample does not
    see keeps gain 0 until fit_all gives it one from all its links).
    positions: {side: [D, 3] m}; index: {side: [M_fit] int64}, each fit link's device on that side; all_index:
    {side: [M] int64}, each link's."""

    def __init__(self, which: str, tx_m: np.ndarray, rx_m: np.ndarray, prior_db: float,
                 tx_id: np.ndarray | None = None, rx_id: np.ndarray | None = None, rows: np.ndarray | None = None):
        super().__init__()
        if which not in CHOICES:
            raise ValueError(f"device gains {which!r} unknown ({', '.join(CHOICES)})")
        if not prior_db > 0:
            raise ValueError("the device gains' prior standard deviation must be > 0 dB")
        self.prior_db = float(prior_db)
        self.positions, self.index, self.all_index, self.ids = {}, {}, {}, {}
        self.gains = nn.ParameterDict()
        for side, pts, ids in zip(SIDES, (tx_m, rx_m), (tx_id, rx_id)):
            if which in (side, "both"):
                uniq, inv, pos = device_index(pts, ids)
                self.positions[side] = pos
                if ids is not None:
                    self.ids[side] = uniq
                self.all_index[side] = torch.as_tensor(inv, dtype=torch.int64)
                self.index[side] = self.all_index[side] if rows is None else \
                    self.all_index[side][torch.as_tensor(np.asarray(rows, np.int64))]
                self.gains[side] = nn.Parameter(torch.zeros(len(pos), dtype=torch.float64))

    @property
    def num_devices(self) -> int:
        return sum(int(g.numel()) for g in self.gains.values())

    @property
    def num_fitted(self) -> int:
        """Devices with at least one fit link (the gains a fit determines)."""
        return sum(int(torch.unique(i).numel()) for i in self.index.values())

    def link_db(self) -> torch.Tensor:
        """Gain of each fit link [M_fit, 1] dB."""
        out = 0.0
        for side, g in self.gains.items():
            out = out + g[self.index[side]]
        return torch.as_tensor(out, dtype=torch.float64).reshape(-1, 1)

    def penalty(self, residual_mse: torch.Tensor, num_links: int) -> torch.Tensor:
        """The prior's term of the per-link loss (module docstring); residual_mse detached by the caller."""
        total = sum((g ** 2).sum() for g in self.gains.values())
        return residual_mse / self.prior_db ** 2 * total / max(num_links, 1)

    @torch.no_grad()
    def profile(self, residual_db: torch.Tensor, weights: torch.Tensor | None = None) -> None:
        """Set the gains to their optimum for the fit links' residuals (measured minus physical prediction, [M_fit]
        dB) with link weights [M_fit] (mean 1; None: all alike): the minimum over g of the fit's loss
        mean_links w (residual - g_tx - g_rx)^2 + penalty, with the penalty's s^2 the weighted mean squared
        residual after the current gains (detached, as the penalty takes it). Per device
        g_d = sum_{links of d} w r / (sum_{links of d} w + s^2 / prior^2); with both sides, side by side until
        the gains move by under 1e-6 dB (warm-started from the current gains)."""
        self._solve(self.index, residual_db, weights)

    @torch.no_grad()
    def fit_all(self, residual_db: torch.Tensor, weights: torch.Tensor | None = None) -> None:
        """profile on every link the devices were built from (residual_db, weights [M]): each device's gain from
        all its links, a device the fit's subsample left out included."""
        self._solve(self.all_index, residual_db, weights)

    def _solve(self, index: dict, residual_db, weights, tol_db: float = 1e-6, max_sweeps: int = 200) -> None:
        r = torch.as_tensor(residual_db, dtype=torch.float64).reshape(-1)
        w = torch.ones_like(r) if weights is None else torch.as_tensor(weights, dtype=torch.float64).reshape(-1)
        gains = self.gains

        def others(side):
            return sum((gains[o][index[o]] for o in index if o != side), torch.zeros_like(r))
        lam = float((w * (r - others(None)) ** 2).sum() / w.sum()) / self.prior_db ** 2 if len(r) else 0.0
        counts = {side: torch.zeros_like(gains[side]).index_add_(0, index[side], w) + lam for side in index}
        for _ in range(max_sweeps if len(index) > 1 else 1):
            moved = 0.0
            for side in index:
                new = torch.zeros_like(gains[side]).index_add_(0, index[side], w * (r - others(side))) / counts[side]
                moved = max(moved, float((new - gains[side]).abs().max()) if new.numel() else 0.0)
                gains[side].copy_(new)
            if moved < tol_db:
                break

    @torch.no_grad()
    def centre(self) -> float:
        """Move each side's mean gain out of the gains and return their sum [dB], to be added to the system gain:
        every link has one device a side, so its prediction is unchanged, and the gains become offsets of mean 0
        about the system gain, the prior's choice along the one direction the links cannot see (an unseen
        device then gets the system gain alone, not the fitted devices' common level)."""
        moved = 0.0
        for g in self.gains.values():
            if g.numel():
                mean = float(g.mean())
                g -= mean
                moved += mean
        return moved

    def table(self) -> dict:
        """{"<side>_pos_m": [D, 3], "<side>_gain_db": [D]} of the fitted sides (artifact fields)."""
        out = {}
        for side, g in self.gains.items():
            out[f"device_{side}_pos_m"] = self.positions[side]
            out[f"device_{side}_gain_db"] = g.detach().numpy().copy()
            if side in self.ids:
                out[f"device_{side}_id"] = np.asarray(self.ids[side], np.int64)
        return out


def device_index(points_m: np.ndarray, ids: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(keys [D], device of each link [M] int64, position of each device [D, 3] m) of links at points_m
    [M, 3] m: devices are the distinct ids [M] where given, else the distinct positions (1 mm). A device
    seen at more than one position (a roaming receiver) has position NaN: it matches no position later."""
    keys = _keys(points_m)
    if ids is None:
        uniq, inv = np.unique(keys, axis=0, return_inverse=True)
        return uniq, inv.reshape(-1), uniq
    uniq, inv = np.unique(np.asarray(ids).reshape(-1), return_inverse=True)
    inv = inv.reshape(-1)
    pos = np.full((len(uniq), 3), np.nan)
    for d in range(len(uniq)):
        at = np.unique(keys[inv == d], axis=0)
        if len(at) == 1:
            pos[d] = at[0]
    return uniq, inv, pos


def gains_at(table: dict, tx_m: np.ndarray, rx_m: np.ndarray) -> tuple[np.ndarray, int]:
    """(gain [N] dB of links tx_m / rx_m [N, 3] from a `DeviceGains.table()`, number of link ends that
    matched a fitted device): a device position the fit saw adds its gain; on a side with one device
    told apart by id (one receiver carried about), that device's gain applies to every link; any other
    link end adds 0."""
    out = np.zeros(len(np.asarray(tx_m).reshape(-1, 3)))
    matched = 0
    for side, pts in zip(SIDES, (tx_m, rx_m)):
        pos, gain = table.get(f"device_{side}_pos_m"), table.get(f"device_{side}_gain_db")
        if pos is None or gain is None or len(gain) == 0:
            continue
        if f"device_{side}_id" in table and len(gain) == 1:
            add = np.full(len(out), float(np.asarray(gain)[0]))
        else:
            lookup = {tuple(p): float(g) for p, g in zip(np.asarray(pos, np.float64), np.asarray(gain, np.float64))
                      if np.isfinite(p).all()}
            add = np.asarray([lookup.get(tuple(k), np.nan) for k in _keys(pts)])
        matched += int(np.isfinite(add).sum())
        out += np.nan_to_num(add, nan=0.0)
    return out, matched


def ridge_gains(residual_db: np.ndarray, index: dict, prior_db: float, sweeps: int = 30) -> dict:
    """Device gains {side: [D] dB} that minimise the fit's device terms for fixed materials: mean over links of
    (residual - g_tx - g_rx)^2 plus the prior (DeviceGains.penalty), solved side by side (each side's gains
    have the closed form g_d = sum_{links of d} r / (n_d + s^2 / prior^2), s^2 the mean squared residual).
    residual_db [M]: measured minus predicted; index {side: [M] int64 device of each link}."""
    r = np.asarray(residual_db, np.float64)
    lam = float(np.mean(r ** 2)) / prior_db ** 2
    gains = {side: np.zeros(int(idx.max()) + 1 if len(idx) else 0) for side, idx in index.items()}
    for _ in range(sweeps if len(index) > 1 else 1):
        for side, idx in index.items():
            rest = r - sum(gains[o][index[o]] for o in index if o != side)
            gains[side] = np.bincount(idx, rest, len(gains[side])) / (np.bincount(idx, None, len(gains[side])) + lam)
    return gains


def whole_device_rows(which: str, count: int, tx_m: np.ndarray, rx_m: np.ndarray, ids: dict) -> np.ndarray:
    """Rows [R] int64 of about `count` of the links tx_m, rx_m [M, 3] m (ids {side: [M] or None}) made of whole
    devices: the fitted side ("tx", "rx" or "both") with the most devices (a gain per surveyed position: a few
    links each) gives evenly spaced devices in device order (device_index: ids, else positions sorted), each with
    every one of its links, so each gain the fit profiles keeps all the links it has; a device of the other side
    (a fixed anchor) keeps its share. All rows when count covers them."""
    sides = [s for s in SIDES if which in (s, "both")]
    device = {s: device_index(p, ids.get(s))[1] for s, p in zip(SIDES, (tx_m, rx_m)) if s in sides}
    side = max(sides, key=lambda s: int(device[s].max()) + 1 if len(device[s]) else 0)
    d = device[side]
    num = int(d.max()) + 1 if len(d) else 0
    if count <= 0 or count >= len(d) or num == 0:
        return np.arange(len(d))
    take = max(1, min(num, int(round(count * num / len(d)))))
    keep = np.zeros(num, bool)
    keep[np.unique(np.linspace(0, num - 1, take).round().astype(np.int64))] = True
    return np.flatnonzero(keep[d])
