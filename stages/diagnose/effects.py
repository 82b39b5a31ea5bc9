"""The catalogue of candidate missing effects: small parametric extensions of the forward model.

Each effect turns the model's prediction P (path gain, dB in `base_db`) into P' = P + correction, with
a few parameters fitted on the training rows. Its signature (what it leaves in the residual
measured - predicted) is in its docstring and in docs/guide/diagnose.md. Power-adding effects work in
linear power: P' = P + A * reference, the reference being free space (links) or the radar equation
for 1 m^2 (monostatic rows), see Rows.reference_power.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares

from .devices import ReceiverOffsets, TransmitterOffsets
from .obstacle import Obstacle
from .rows import Rows

from .effect_base import FLOOR, Effect, _add_power, _db  # noqa: F401  (FLOOR: part of the catalogue's API)


class GainOffset(Effect):
    """A constant gain or cable loss: the residual is the same constant everywhere."""

    name, title, params, x0 = "gain_offset", "constant gain / cable loss", ("offset_db",), ((0.0,),)

    def correction(self, x, rows, base_db):
        return np.full(rows.num, x[0])


class PathLossExponent(Effect):
    """A distance exponent other than the model's: the residual grows linearly in log10(distance)."""

    name, title = "path_loss_exponent", "path-loss exponent different from free space"
    params, x0 = ("extra_exponent", "offset_db"), ((0.0, 0.0), (0.5, 0.0), (-0.5, 0.0))

    def applies(self, rows):
        d = rows.dist_m
        return bool(d.max() / max(d.min(), 1e-9) > 1.5), "the distances span less than a factor 1.5"

    def correction(self, x, rows, base_db):
        return x[1] - 10 * x[0] * np.log10(rows.dist_m / np.median(rows.dist_m))


class AntennaPattern(Effect):
    """An antenna pattern mismatch: the residual depends smoothly on the elevation of the link."""

    name, title = "antenna_pattern", "antenna pattern mismatch (elevation)"
    params, x0 = ("sin2_db", "sin4_db", "offset_db"), ((0.0, 0.0, 0.0),)

    def applies(self, rows):
        if rows.monostatic:
            return False, "monostatic rows all look along the antenna's boresight"
        el = rows.elevation_rad()
        return bool(np.ptp(el) > math.radians(10)), "the links' elevations span less than 10 deg"

    def correction(self, x, rows, base_db):
        s2 = np.sin(rows.elevation_rad()) ** 2
        return x[0] * s2 + x[1] * s2**2 + x[2]


class GroundBounce(Effect):
    """A floor or ground bounce: a mirror image through a horizontal plane at height h adds a ray that
    interferes with the direct one; the residual oscillates with the path difference (two-ray lobes)."""

    name, title = "ground_bounce", "floor / ground bounce (two-ray)"
    params = ("reflection", "plane_height_m")

    def _geometry(self, rows, h):
        tx = rows.tx_m
        target = rows.rx_m if not rows.monostatic else np.broadcast_to(_turntable_centre(rows), tx.shape)
        direct = np.linalg.norm(target - tx, axis=1)
        mirror = target.copy()
        mirror[:, 2] = 2 * h - target[:, 2]
        image = np.linalg.norm(mirror - tx, axis=1)
        return direct, image

    def correction(self, x, rows, base_db):
        rho, h = x
        direct, image = self._geometry(rows, h)
        k = 2 * np.pi / rows.wavelength_m
        factor = np.abs(1 + rho * direct / image * np.exp(-1j * k * (image - direct))) ** 2
        return _db(factor ** (2 if rows.monostatic else 1))

    def fit(self, rows, base_db, mask):
        z = np.concatenate([rows.tx_m[:, 2], rows.rx_m[:, 2]])
        best, best_cost = np.array([0.0, z.min() - 1.0]), math.inf
        target = rows.meas_db - base_db
        for h in np.linspace(z.min() - 2.0, z.min() - 0.05, 40):   # the plane lies below every antenna
            for rho in (-0.7, -0.3, 0.3, 0.7):
                r = target - self.correction(np.array([rho, h]), rows, base_db)
                cost = np.sum(np.sqrt(1 + r[mask] ** 2) - 1)
                if cost < best_cost:
                    best, best_cost = np.array([rho, h]), cost
        sol = least_squares(lambda x: (target - self.correction(x, rows, base_db))[mask], best, loss="soft_l1",
                            bounds=([-1.0, best[1] - 0.3], [1.0, best[1] + 0.3]), max_nfev=100)
        return sol.x


class DoubleBounce(Effect):
    """Second-order (double-bounce) reflections: extra power arriving over a longer path, d + L; it
    fills in where the model is weak and falls off more slowly with distance than the direct path."""

    name, title = "double_bounce", "second-order (double-bounce) reflections"
    params, x0 = ("level_db", "extra_path_m"), ((-10.0, 3.0), (-20.0, 8.0), (0.0, 1.0))
    lower, upper = (-60.0, 0.0), (30.0, 50.0)

    def applies(self, rows):
        return (not rows.monostatic), "monostatic: use diffuse_lobe / leakage"

    def correction(self, x, rows, base_db):
        lam = rows.wavelength_m
        return _add_power(base_db, 10 ** (x[0] / 10) * (lam / (4 * np.pi * (rows.dist_m + x[1]))) ** 2)

    def consistent(self, x, rows, mask):
        # An extra path at its upper bound makes the added power nearly the same on every link: the fit
        # wants a constant (a noise floor), not a longer path, and would win over it only by its extra
        # parameter's freedom (a noise floor hidden in a room scored within 2 % of the floor itself).
        ok = x[1] < self.upper[1] * (1 - 1e-6)
        return ok, "" if ok else (f"the extra path sits at its bound ({self.upper[1]:g} m): the added power is "
                                  "nearly constant over the links, a noise floor rather than a double bounce")


class DiffuseLobe(Effect):
    """A missing diffuse-scattering lobe: incoherent power proportional to the smooth reference level;
    it fills the model's nulls and barely touches its strong returns."""

    name, title, params = "diffuse_lobe", "missing diffuse scattering", ("level_db",)
    x0 = ((-20.0,), (-5.0,), (-35.0,))
    lower, upper = (-80.0,), (30.0,)

    def correction(self, x, rows, base_db):
        return _add_power(base_db, 10 ** (x[0] / 10) * rows.reference_power())

    def consistent(self, x, rows, mask):
        if not (rows.monostatic and rows.meas_channel is not None and rows.aspect_rad is not None):
            return True, ""
        added = float(_db(np.median(10 ** (x[0] / 10) * rows.reference_power()[mask])))
        coh = coherent_mean_db(rows, mask)
        ok = coh < added - COHERENCE_DB
        return ok, "" if ok else f"the added power is coherent ({coh:.1f} vs {added:.1f} dB): leakage, not diffuse"


class EdgeDiffraction(Effect):
    """Edge diffraction into shadowed regions: power appears where the direct segment is blocked,
    independent of how many objects block it."""

    name, title, params = "edge_diffraction", "edge diffraction into shadowed regions", ("level_db",)
    x0 = ((-15.0,), (-30.0,))
    lower, upper = (-80.0,), (10.0,)

    def applies(self, rows):
        if rows.crossings is None:
            return False, "needs geometry (--geometry) to know which links are shadowed"
        return bool((rows.crossings > 0).sum() >= 10), "fewer than 10 shadowed links"

    def correction(self, x, rows, base_db):
        return _add_power(base_db, (rows.crossings > 0) * 10 ** (x[0] / 10) * rows.reference_power())


class WallTransmission(Effect):
    """Transmission through walls: the direct path is still there behind obstacles, weakened by a loss
    per object crossed, so the residual grows with the free-space level and falls with the crossings."""

    name, title, params = "wall_transmission", "transmission through walls / objects", ("loss_per_crossing_db",)
    x0 = ((-3.0,), (-10.0,), (-20.0,))
    lower, upper = (-60.0,), (0.0,)

    def applies(self, rows):
        return EdgeDiffraction.applies(self, rows)

    def correction(self, x, rows, base_db):
        n = rows.crossings
        return _add_power(base_db, (n > 0) * 10 ** (x[0] * n / 10) * rows.reference_power())


class CrossingLoss(Effect):
    """A loss (or gain) per crossing of an object: each object on the direct segment changes the link by
    the same dB, of either sign (a glass partition the model treats as transparent, or one it makes
    too opaque); the residual is a step per crossing count, LoS rows untouched."""

    name, title, params = "crossing_loss", "loss or gain per object crossed", ("db_per_crossing",)
    x0 = ((-3.0,), (3.0,))

    def applies(self, rows):
        return EdgeDiffraction.applies(self, rows)

    def correction(self, x, rows, base_db):
        return x[0] * rows.crossings


class Ripple(Effect):
    """A frequency-dependent system response: a sinusoidal ripple over frequency, the same for every link."""

    name, title = "ripple", "frequency-dependent system response (ripple)"
    params = ("amplitude_db", "period_hz", "phase_rad", "offset_db")

    def applies(self, rows):
        return bool(len(np.unique(rows.freq_hz)) >= 8), "fewer than 8 frequencies"

    def correction(self, x, rows, base_db):
        f0 = rows.freq_hz.min()
        return x[0] * np.sin(2 * np.pi * (rows.freq_hz - f0) / x[1] + x[2]) + x[3]

    def fit(self, rows, base_db, mask):
        f = rows.freq_hz[mask]
        r = (rows.meas_db - base_db)[mask]
        band = max(np.ptp(rows.freq_hz), 1.0)
        nf = len(np.unique(rows.freq_hz))
        best, best_cost = None, math.inf
        for period in band / np.linspace(0.5, nf / 3, 120):    # from half a cycle to a few samples per cycle
            w = 2 * np.pi * (f - rows.freq_hz.min()) / period
            a = np.stack([np.sin(w), np.cos(w), np.ones_like(w)], 1)
            coef = np.linalg.lstsq(a, r, rcond=None)[0]
            cost = np.sum(np.abs(r - a @ coef))
            if cost < best_cost:
                best_cost = cost
                best = np.array([np.hypot(coef[0], coef[1]), period, math.atan2(coef[1], coef[0]), coef[2]])
        sol = least_squares(lambda x: (rows.meas_db - base_db - self.correction(x, rows, base_db))[mask], best,
                            loss="soft_l1", max_nfev=200)
        return sol.x


def coherent_mean_db(rows: Rows, mask: np.ndarray) -> float:
    """Power of the coherent centre of the measured channel over the rows in mask, per frequency,
    averaged [dB]. An echo whose phase turns with the aspect averages out; a constant coupling does not.
    The centre is the median of the real and of the imaginary parts: a few strong glints move a mean
    as much as a weak coupling does, but not a median. When the model gives phase, the centre of the
    measured minus the predicted channel (the echo need not average out then)."""
    levels = []
    meas = rows.meas_channel
    if rows.pred_channel is not None:   # the model gives phase: what it does not explain
        meas = meas - rows.pred_channel
    for f in np.unique(rows.freq_hz[mask]):
        h = meas[mask & (rows.freq_hz == f)]
        levels.append(np.median(h.real) ** 2 + np.median(h.imag) ** 2)
    return float(_db(np.mean(levels)))


class Leakage(Effect):
    """Direct Tx-Rx leakage in a monostatic radar: a constant coupling added to the channel, the same at
    every aspect and range, that dominates wherever the target's echo is weak. A diffuse return adds
    power of the same form at one range, but no coherent mean: the echo's phase turns with the aspect
    and averages out, the coupling's does not. So leakage is only accepted when the coherent mean of
    the measured channel matches its fitted level (within COHERENCE_DB), and a diffuse lobe only when
    it does not."""

    name, title, params = "leakage", "direct Tx-Rx leakage (monostatic)", ("level_db",)
    needs_phase = True
    x0 = ((-60.0,), (-90.0,), (-120.0,))
    lower, upper = (-250.0,), (0.0,)

    def applies(self, rows):
        if not rows.monostatic:
            return False, "only for monostatic (co-located Tx and Rx) data"
        if rows.meas_channel is None:
            return False, "needs the measured complex channel (phase)"
        if rows.aspect_rad is None or len(np.unique(np.round(rows.aspect_rad, 6))) < 12:
            return False, "needs at least 12 aspects to average the echo out"
        return True, ""

    def correction(self, x, rows, base_db):
        if rows.pred_channel is not None and len(x) == 3:   # coherent: |S + L|^2 with the model's own phase
            s = rows.pred_channel * 10 ** ((base_db - _db(np.abs(rows.pred_channel) ** 2)) / 20)
            return _db(np.abs(s + x[1] + 1j * x[2]) ** 2) - base_db
        return _add_power(base_db, np.full(rows.num, 10 ** (x[0] / 10)))

    def fit(self, rows, base_db, mask):
        if rows.pred_channel is None:
            return super().fit(rows, base_db, mask)
        # the model gives phase: the coupling is the mean of measured - predicted channel
        s = rows.pred_channel * 10 ** ((base_db - _db(np.abs(rows.pred_channel) ** 2)) / 20)
        leak = np.mean((rows.meas_channel - s)[mask])
        return np.array([_db(abs(leak) ** 2), leak.real, leak.imag])

    def describe(self, x):
        d = {"level_db": float(x[0])}
        if len(x) == 3:
            d["phase_deg"] = float(np.degrees(np.arctan2(x[2], x[1])))
        return d

    def consistent(self, x, rows, mask):
        coh = coherent_mean_db(rows, mask)
        ok = abs(coh - x[0]) <= COHERENCE_DB
        return ok, "" if ok else f"the measured channel's coherent mean ({coh:.1f} dB) does not match {x[0]:.1f} dB"


COHERENCE_DB = 4.0


class NoiseFloor(Effect):
    """A receiver noise floor: a constant power added to every link, visible where the signal is weak."""

    name, title, params = "noise_floor", "receiver noise floor", ("floor_db",)
    x0 = ((-80.0,), (-100.0,), (-60.0,))
    lower, upper = (-250.0,), (0.0,)

    def applies(self, rows):
        return (not rows.monostatic), "monostatic: a constant power is the leakage candidate"

    def correction(self, x, rows, base_db):
        return _add_power(base_db, np.full(rows.num, 10 ** (x[0] / 10)))


def _clip_level(effect, rows, base_db, mask, q_lo: float, q_hi: float) -> np.ndarray:
    """[level_db]: the clip level among 41 quantiles q_lo..q_hi of the model's training predictions that
    minimises the absolute residual of effect.correction (saturation from above, a floor from below)."""
    r = rows.meas_db - base_db
    levels = np.quantile(base_db[mask], np.linspace(q_lo, q_hi, 41))
    costs = [np.sum(np.abs(r - effect.correction(np.array([lv]), rows, base_db))[mask]) for lv in levels]
    return np.array([levels[int(np.argmin(costs))]])


class Saturation(Effect):
    """Receiver saturation: the strongest links read lower than predicted, clipped at a level."""

    name, title, params = "saturation", "receiver saturation", ("level_db",)

    def correction(self, x, rows, base_db):
        return np.minimum(base_db, x[0]) - base_db

    def fit(self, rows, base_db, mask):
        return _clip_level(self, rows, base_db, mask, 0.5, 1.0)


class DynamicRange(Effect):
    """A dynamic-range limit: the receiver reports nothing below a floor, so every weaker link reads the
    floor itself (a clip from below; a noise floor adds power instead)."""

    name, title, params = "dynamic_range", "dynamic-range limit (weak links read a floor)", ("floor_db",)

    def correction(self, x, rows, base_db):
        return np.maximum(base_db, x[0]) - base_db

    def fit(self, rows, base_db, mask):
        return _clip_level(self, rows, base_db, mask, 0.0, 0.5)


class TurntableOffset(Effect):
    """A turntable or positioning offset: the measured pattern is the model's pattern shifted in aspect."""

    name, title, params = "turntable_offset", "turntable / positioning offset", ("offset_deg",)

    def applies(self, rows):
        if rows.aspect_rad is None:
            return False, "no aspect angles in the data"
        return bool(len(np.unique(np.round(rows.aspect_rad, 6))) >= 36), "fewer than 36 aspects"

    def correction(self, x, rows, base_db):
        out = np.zeros(rows.num)
        shift = math.radians(x[0])
        for c in np.unique(rows.curve_id):
            i = np.flatnonzero(rows.curve_id == c)
            order = np.argsort(rows.aspect_rad[i])
            a, v = rows.aspect_rad[i][order], base_db[i][order]
            shifted = np.interp(np.mod(rows.aspect_rad[i] + shift, 2 * np.pi), a, v, period=2 * np.pi)
            out[i] = shifted - base_db[i]
        return out

    def fit(self, rows, base_db, mask):
        r = rows.meas_db - base_db
        grid = np.arange(-10.0, 10.01, 0.25)
        costs = [np.sum(np.abs(r - self.correction(np.array([g]), rows, base_db))[mask]) for g in grid]
        g0 = grid[int(np.argmin(costs))]
        fine = np.arange(g0 - 0.25, g0 + 0.26, 0.05)
        costs = [np.sum(np.abs(r - self.correction(np.array([g]), rows, base_db))[mask]) for g in fine]
        return np.array([fine[int(np.argmin(costs))]])


def _turntable_centre(rows: Rows) -> np.ndarray:
    """[3] the point the radar circles (mean of the radar positions)."""
    return rows.tx_m.mean(0)



CATALOGUE: tuple[Effect, ...] = (GainOffset(), PathLossExponent(), AntennaPattern(), GroundBounce(), DoubleBounce(),
                                 DiffuseLobe(), EdgeDiffraction(), WallTransmission(), CrossingLoss(), Ripple(),
                                 Leakage(), NoiseFloor(), DynamicRange(), Saturation(), TurntableOffset(),
                                 TransmitterOffsets(), ReceiverOffsets(), Obstacle())
BY_NAME = {e.name: e for e in CATALOGUE}
