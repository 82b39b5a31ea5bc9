"""A regularised residual on top of the fitted physical model (docs/physics.md).

The materials are fitted first and then held fixed; the residual adds freedom the physics lacks
(facets the surfels miss, edge waves, small errors of level), with a weight chosen by validation on
training rows only. Weight infinity (the physics alone) is always a candidate, and its validation
error is reported beside the chosen one.

Two forms:
- "smooth": a correction in dB that varies smoothly with the link geometry, the posterior mean of a
  zero-mean Gaussian process fitted to the training residual r = measured - physical (dB), one per
  fitted frequency:
      delta(x) = k(x, X) (K + eta I)^-1 r,
      k(x, x') = exp(-(a_tx^2 + a_rx^2) / (4 l^2)) exp(-(ln rho - ln rho')^2 / (2 l_rho^2)),
  a_tx, a_rx the angles between the two links' transmitter (receiver) directions seen from the scene
  centre (for a monostatic radar on a turntable: the aspect difference), rho the antennas' mean
  distance from the centre. Lengths l, l_rho and the weight eta (noise over prior variance) are chosen
  by validation (`choose`: the physics alone unless a candidate beats it by one standard error).
  Zero prior mean: farther than a few l from every training link the correction is zero and the
  physics predicts alone (a held-out sector); at a frequency that was not fitted it is zero too.
  The physics enters both kernel forms floored at BELOW_WEAKEST_DB under the weakest training row:
  where it predicts no echo at all (a plate edge-on, PO's zero) the residual would otherwise learn a
  correction of hundreds of dB and spread it over the neighbouring aspects.
- "blend": near the training links the measurement itself, interpolated by the same kernel, far from
  them the physics:
      pred(x) = s(x) I(x) + (1 - s(x)) phys(x),  I(x) = mean(y) + k(x, X) (K + eta I)^-1 (y - mean(y)),
      s(x) = k(x, X) (K + eta I)^-1 k(X, x) in [0, 1]
  (s: the share of the prior variance the training links explain at x). The smooth form adds the
  physics' own fine structure between training aspects (pred = interpolated y + phys(x) -
  interpolated phys), which hurts where that structure is wrong (a null of the physics the object
  does not have, 1 degree off); the blend does not, and still gives way to the physics in a
  held-out sector. "auto" offers both forms' candidates to the same validation.
- "gaussian": a complex factor per surfel, each surfel's specular term times (1 + r_g), fitted by Adam
  on the dB error with the penalty lambda sum_g |r_g|^2 / (links x frequencies); surfels no training
  link lights get no gradient and stay at 0. Its correction of a held-out aspect is a coherent sum of
  per-surfel changes whose phases turn with aspect, not a local interpolation of the training rows.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np
import torch

from rfir_core.threads import single_thread_torch

from rfir_core.physics.materials import abs2
from .physical import MaterialValues, PairGeometry, scattered_field, specular_terms
from .validation_folds import aspect_index, distinct_aspects, validation_folds

FORMS = ("auto", "smooth", "blend", "gaussian", "off")
INTERPOLATION = ("half-spacing", "validated")   # the residual between training aspects (ResidualConfig.interpolation)
KERNEL_FORMS = {"auto": ("smooth", "blend"), "smooth": ("smooth",), "blend": ("blend",)}
KFOLDS = 5          # interpolation protocols: every 5th training aspect held out in turn
FLOOR_DB = -250.0   # as predict.FLOOR_DB (a link that sees no lit surfel)
MIN_FOLD_LINKS = 50  # the gaussian form validates on its first fold alone when that holds this many links
SE_MARGIN = 1.0    # choose: standard errors by which a residual must beat the physics alone
BELOW_WEAKEST_DB = 30.0   # smooth / blend: the physics is floored this far below the weakest training row


@dataclass
class ResidualConfig:
    """[rf_fit.physical] residual settings (configs/rf_fit.toml documents each)."""

    form: str = "auto"
    weight: float | None = None              # None: chosen by validation; inf: physics only
    weights: tuple = (0.03, 0.3, 3.0)        # smooth / blend: eta candidates
    lengths_deg: tuple = (1.0, 2.0, 4.0, 8.0)
    sector_lengths_deg: tuple = (1.0, 2.0, 4.0)   # a held-out sector's candidates (residual_sector_lengths_deg)
    range_lengths: tuple = (0.1, 1.0)        # l_rho, in ln(range)
    gaussian_weights: tuple = (0.3, 3.0, 30.0)
    iterations: int = 150
    lr: float = 0.05
    interpolation: str = "half-spacing"      # data / every-N protocols (fit_smooth's spacing_deg)


@dataclass
class ResidualFit:
    """A fitted residual. form "off": none. params: smooth / blend: {"tx_m", "rx_m" [T, 3], "weights_db"
    [T, F], "mean_db" [F] (blend; 0 for smooth), "length_deg", "range_length", "weight"}; gaussian:
    {"surfel" [G] complex, "weight"}.
    validation: {candidate name: pooled validation MAE dB}, with "physics only" always present."""

    form: str
    params: dict = field(default_factory=dict)
    validation: dict = field(default_factory=dict)
    chosen: str = "physics only"
    how: str = ""
    wall_time_s: float = 0.0


# ----- link coordinates and the kernel (smooth form) -----

def link_coords(tx_m: np.ndarray, rx_m: np.ndarray, centre: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(transmitter direction [L, 3], receiver direction [L, 3], ln of the mean antenna distance [L])
    seen from the scene centre [3] m."""
    vt, vr = np.asarray(tx_m, float) - centre, np.asarray(rx_m, float) - centre
    dt, dr = np.linalg.norm(vt, axis=1), np.linalg.norm(vr, axis=1)
    return vt / dt[:, None], vr / dr[:, None], np.log(0.5 * (dt + dr))


def link_distances(a, b) -> tuple[np.ndarray, np.ndarray]:
    """(a_tx^2 + a_rx^2 [La, Lb] rad^2, (ln rho - ln rho')^2 [La, Lb]) between coordinates a, b from
    link_coords: what the kernel depends on, apart from its lengths."""
    at = np.arccos(np.clip(_mm(a[0], b[0].T), -1.0, 1.0))
    ar = np.arccos(np.clip(_mm(a[1], b[1].T), -1.0, 1.0))
    return at**2 + ar**2, (a[2][:, None] - b[2][None]) ** 2


def kernel_of_distances(angle_sq: np.ndarray, log_range_sq: np.ndarray, length_rad: float,
                        range_length: float) -> np.ndarray:
    """k (module docstring) from link_distances' output."""
    return np.exp(-angle_sq / (4 * length_rad**2) - log_range_sq / (2 * range_length**2))


def kernel(a, b, length_rad: float, range_length: float) -> np.ndarray:
    """k(a_i, b_j) [La, Lb] for coordinates a, b from link_coords (module docstring)."""
    return kernel_of_distances(*link_distances(a, b), length_rad, range_length)


def training_spacing_deg(aspect_deg: np.ndarray) -> float | None:
    """The training aspects' spacing, degrees: the median over the distinct training aspects of the angle
    to the nearest other one (other ranges and frequencies of an aspect do not count; for a monostatic
    radar the kernel's angle between two links is their aspect difference). None for fewer than two."""
    u = distinct_aspects(aspect_deg)[0]
    if len(u) < 2:
        return None
    gap = np.diff(np.concatenate([u, u[:1] + 360.0]))                 # to the next aspect round the circle
    return float(np.median(np.minimum(gap, np.roll(gap, 1))))


# The linear algebra runs in torch, one thread (callers hold single_thread_torch): a model selection is
# ~100 factorisations of ~1000 x 1000, each too small to share between threads; on a busy 2-core CPU
# the multi-threaded BLAS behind numpy/scipy spent 8x the time waiting for its own threads
# (bench/bench_rf_fit.py).

def _mm(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a @ b (float64) by torch."""
    return (torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64))
            @ torch.from_numpy(np.ascontiguousarray(b, dtype=np.float64))).numpy()


def _factor(k_fit: np.ndarray, eta: float) -> torch.Tensor:
    """Lower Cholesky factor of K + eta I."""
    k = torch.from_numpy(np.array(k_fit, dtype=np.float64))
    k.diagonal().add_(eta)
    return torch.linalg.cholesky(k)


def _solve(factor: torch.Tensor, b: np.ndarray) -> np.ndarray:
    """(K + eta I)^-1 b for the factor of K + eta I (b [T] or [T, F])."""
    b = np.asarray(b, dtype=np.float64)
    x = torch.cholesky_solve(torch.from_numpy(np.ascontiguousarray(b.reshape(len(b), -1))), factor)
    return x.numpy().reshape(b.shape)


def _form_at(kind: str, k_new: np.ndarray, factor, weights_db: np.ndarray, mean_db: np.ndarray,
             phys_new: np.ndarray) -> np.ndarray:
    """Prediction [V, F] dB of the smooth / blend form (module docstring) from k(x, X) [V, T], the
    factor of K + eta I, the fitted weights [T, F] and mean [F], and the physics there [V, F]."""
    corr = _mm(k_new, weights_db)
    if kind == "smooth":
        return phys_new + corr
    # s = k (K + eta I)^-1 k^T = |L^-1 k^T|^2 per column, L the factor: one triangular solve, not two
    half = torch.linalg.solve_triangular(factor, torch.from_numpy(np.ascontiguousarray(k_new.T)), upper=False)
    share = np.clip((half * half).sum(0).numpy(), 0.0, 1.0)[:, None]
    return share * (mean_db[None] + corr) + (1.0 - share) * phys_new


def _pick(c, rows):
    return tuple(x[rows] for x in c)


def smooth_weights(coords, resid_db: np.ndarray, length_rad: float, range_length: float, eta: float) -> np.ndarray:
    """(K + eta I)^-1 r [T, F] for training coordinates and residuals r [T, F] dB."""
    with single_thread_torch():
        return _solve(_factor(kernel(coords, coords, length_rad, range_length), eta), resid_db)


def smooth_correction(coords_train, weights_db: np.ndarray, coords, length_rad: float, range_length: float,
                      chunk: int = 4096) -> np.ndarray:
    """delta [L, F] dB at coordinates `coords` (link_coords) from smooth_weights' output."""
    out = np.zeros((len(coords[0]), weights_db.shape[1]))
    with single_thread_torch():
        for a in range(0, len(out), chunk):
            sl = slice(a, a + chunk)
            out[sl] = _mm(kernel(_pick(coords, sl), coords_train, length_rad, range_length), weights_db)
    return out


# ----- validation folds -----

def residual_folds(protocol: str, aspect_deg: np.ndarray | None, range_m: np.ndarray | None,
                   num_rows: int) -> tuple[list[np.ndarray], str]:
    """Folds of training rows for choosing the residual, shaped like the protocol's test: blocks of
    training aspects as wide as a held-out sector (`sector_blocks`), each training range in turn
    (validation_folds.validation_folds); for the interpolation protocols (data, every-N) whole training
    aspects (every range of them), every KFOLDS-th aspect in turn, so that no fold is predicted from its own
    aspect at another range."""
    name, _, arg = protocol.partition(":")
    if name == "sector" and aspect_deg is not None:
        return sector_blocks(aspect_deg, *(float(x) for x in arg.split(":")))
    if name == "range" or aspect_deg is None:
        return validation_folds(protocol, aspect_deg, range_m)
    inv = aspect_index(aspect_deg)
    k = min(KFOLDS, int(inv.max()) + 1 if inv.size else 0)
    if k < 2:
        return [np.arange(0, num_rows, 10)], "every 10th training row"
    return [np.flatnonzero(inv % k == j) for j in range(k)], f"{k}-fold, every {k}th training aspect in turn"


def sector_blocks(aspect_deg: np.ndarray, a_deg: float, b_deg: float) -> tuple[list[np.ndarray], str]:
    """Folds for a held-out sector [a, b) degrees: the training aspects cut into contiguous blocks about as
    wide as the sector (at least 2), going round from its end, each held out in turn. A block is predicted
    across a gap like the sector's, so the validation sees how far a residual carries into unmeasured
    aspects; chosen on the rows next to the sector alone (validation_folds.validation_folds), residuals lost to
    the physics alone inside the sector on 8 of 14 measured rows."""
    width = (b_deg - a_deg) % 360.0 or 360.0
    off = np.mod(np.asarray(aspect_deg, float) - b_deg, 360.0)          # from the sector's end, 0 .. 360 - width
    span = max(360.0 - width, 1e-9)
    k = max(2, int(round(span / width)))
    block = np.minimum((off / span * k).astype(np.int64), k - 1)
    folds = [np.flatnonzero(block == j) for j in range(k)]
    folds = [f for f in folds if f.size]
    return folds, f"{len(folds)} blocks of training aspects about as wide as the sector, each in turn"


# ----- fitting -----

def physics_db(pairs: PairGeometry, material_of_gaussian: torch.Tensor, mats: MaterialValues, gain_db: float,
               surfel_factor: torch.Tensor | None = None) -> np.ndarray:
    """Predicted path gain [M, K] dB of the pairs' links (the exact pair sum, as prediction computes it)."""
    with torch.no_grad():
        f, d = scattered_field(pairs, material_of_gaussian, mats, surfel_factor=surfel_factor)
        p = (f.abs() ** 2 + d).numpy() * 10 ** (gain_db / 10)
    return np.maximum(10 * np.log10(np.maximum(p, 1e-300)), FLOOR_DB)


def choose(errors: dict) -> tuple[str, dict]:
    """(chosen candidate, {candidate: validation MAE dB}) from each candidate's absolute validation
    errors (same entries; "physics only" among them). The one-standard-error rule: the lowest MAE wins
    only when it beats the physics alone (the simplest candidate) by more than SE_MARGIN standard errors
    of their paired difference (`beats`); otherwise the physics alone is kept (a residual that fits noise must not be
    chosen by the luck of the folds).

    Why one and not two: the validation folds hold out whole training aspects, so a held-out aspect
    lies twice as far from the remaining ones as a test aspect of the even/odd protocol lies from the
    training ones; validation understates what an interpolating residual gains on dense rows, and a
    stricter margin rejected residuals that halved the test error."""
    scores = {k: float(np.mean(v)) for k, v in errors.items()}
    best = min(scores, key=scores.get)
    keep = best == "physics only" or beats(errors[best], errors["physics only"])
    return (best if keep else "physics only"), scores


def beats(errors_a: np.ndarray, errors_b: np.ndarray) -> bool:
    """Whether candidate a's absolute validation errors are lower than b's (same entries) by more than
    SE_MARGIN standard errors of their paired difference."""
    d = (np.asarray(errors_a) - np.asarray(errors_b)).ravel()
    return bool(d.mean() < -SE_MARGIN * d.std(ddof=1) / math.sqrt(max(d.size, 2)))


def kernel_predict(kind: str, coords_fit, y_fit: np.ndarray, phys_fit: np.ndarray, coords_new, phys_new: np.ndarray,
                   length_rad: float, range_length: float, eta: float) -> tuple[np.ndarray, dict]:
    """(prediction [V, F] dB at coords_new, the fitted {"weights_db", "mean_db"}) of the smooth or blend
    form from training rows (y_fit measured, phys_fit physical, [T, F] dB)."""
    if kind == "smooth":
        mean = np.zeros(y_fit.shape[1])
        w = smooth_weights(coords_fit, y_fit - phys_fit, length_rad, range_length, eta)
    else:
        mean = y_fit.mean(0)
        w = smooth_weights(coords_fit, y_fit - mean, length_rad, range_length, eta)
    params = {"weights_db": w, "mean_db": mean}
    return blend_at(kind, coords_fit, params, coords_new, phys_new, length_rad, range_length, eta), params


def blend_at(kind: str, coords_fit, params: dict, coords_new, phys_new: np.ndarray, length_rad: float,
             range_length: float, eta: float, chunk: int = 2048) -> np.ndarray:
    """Prediction [V, F] dB of a fitted smooth / blend form (module docstring) where the physics gives
    phys_new [V, F] (columns: the fitted frequencies)."""
    with single_thread_torch():
        factor = None if kind == "smooth" else _factor(kernel(coords_fit, coords_fit, length_rad, range_length), eta)
        out = np.zeros(np.shape(phys_new))
        for a in range(0, len(out), chunk):
            sl = slice(a, a + chunk)
            kn = kernel(_pick(coords_new, sl), coords_fit, length_rad, range_length)   # [v, T]
            out[sl] = _form_at(kind, kn, factor, params["weights_db"], params["mean_db"], phys_new[sl])
    return out


def _select(coords, folds: list[np.ndarray], grid: list, target_db: np.ndarray, phys_db: np.ndarray,
            preds: dict) -> None:
    """Every candidate (kind, l, l_rho, eta) of `grid` on every fold, as kernel_predict computes it,
    appended to preds[candidate] ([V, F] dB per fold), with the link distances found once and one
    factor of K + eta I per (fold, l, l_rho, eta) shared by both forms: the same numbers at a fraction
    of the cost (the kernels and factors are the bulk of a large fit's model selection)."""
    m = len(target_db)
    angle_sq, log_range_sq = link_distances(coords, coords)
    for val in folds:
        rows = np.setdiff1d(np.arange(m), val)
        fit_fit, new_fit = np.ix_(rows, rows), np.ix_(val, rows)
        y, phys = target_db[rows], phys_db[rows]
        for ld, lr in dict.fromkeys((g[1], g[2]) for g in grid):
            k_fit = kernel_of_distances(angle_sq[fit_fit], log_range_sq[fit_fit], math.radians(ld), lr)
            k_new = kernel_of_distances(angle_sq[new_fit], log_range_sq[new_fit], math.radians(ld), lr)
            for eta in dict.fromkeys(g[3] for g in grid if g[1:3] == (ld, lr)):
                factor = _factor(k_fit, eta)
                for kind in dict.fromkeys(g[0] for g in grid if g[1:] == (ld, lr, eta)):
                    mean = np.zeros(y.shape[1]) if kind == "smooth" else y.mean(0)
                    weights = _solve(factor, y - (phys if kind == "smooth" else mean[None]))
                    preds[(kind, ld, lr, eta)].append(_form_at(kind, k_new, factor, weights, mean, phys_db[val]))


def half_spacing_length_deg(cfg: ResidualConfig, spacing_deg: float) -> float:
    """The half-spacing candidate's length [deg]: half the training spacing, at most the longest validated
    length (no correction reaches further than any candidate would)."""
    return min(0.5 * spacing_deg, max(cfg.lengths_deg))


def visible_lengths(cfg: ResidualConfig, spacing_deg: float | None) -> tuple:
    """The validated candidates' lengths [deg]: cfg.lengths_deg, without those shorter than half the
    training spacing where one is given (fit_smooth: validation cannot see them)."""
    return tuple(ld for ld in cfg.lengths_deg if spacing_deg is None or ld >= 0.5 * spacing_deg)


def fit_smooth(coords, phys_db: np.ndarray, target_db: np.ndarray, folds: list[np.ndarray], cfg: ResidualConfig,
               how: str, spacing_deg: float | None = None) -> ResidualFit:
    """Choose the kernel form (smooth / blend, as cfg.form allows) and its (l, l_rho, eta) by validation
    over `folds` (physics only among the candidates, `choose`) and fit it on every training row.
    coords: link_coords of the training rows; [M, K] arrays.

    spacing_deg: the training aspects' spacing where the test links lie between training links (the data
    and every-N protocols, ResidualConfig.interpolation "half-spacing"): a candidate of half that length
    (`half_spacing_length_deg`) and the smallest weight (l_rho validated) is kept unless a validated candidate beats both it and the
    physics alone by one standard error: it is applied even where the physics alone validates better.
    Why: a held-out training aspect lies a whole spacing from the rest, twice as far as any test aspect,
    and the two can disagree in sign where the residual decorrelates within a spacing; where a longer
    length wins on validation (a smooth curve) it wins at the test aspects too. The physics alone is
    still scored and reported.
    With spacing_deg, validated candidates shorter than half of it are not offered (`visible_lengths`):
    at a held-out aspect a whole spacing from the rest such a kernel is nearly zero, so validation
    scores it as the physics alone while at the test aspects, half a spacing away, it moves the
    prediction; the one-standard-error test would then pass on a difference of hundredths of a dB and
    keep a kernel that changes the test aspects unvalidated."""
    t0 = time.time()
    val_all = np.concatenate(folds)
    errors = {"physics only": np.abs(phys_db[val_all] - target_db[val_all])}
    floor_db = np.min(target_db, axis=0) - BELOW_WEAKEST_DB          # [F] (module docstring)
    phys_db = np.maximum(phys_db, floor_db[None])                      # what the kernel forms see
    weights = (cfg.weight,) if cfg.weight is not None else cfg.weights
    grid = [(kind, ld, lr, eta) for kind in KERNEL_FORMS[cfg.form] for ld in visible_lengths(cfg, spacing_deg)
            for lr in cfg.range_lengths for eta in weights]
    local = [] if spacing_deg is None else [(KERNEL_FORMS[cfg.form][0], half_spacing_length_deg(cfg, spacing_deg), lr,
                                             min(weights)) for lr in cfg.range_lengths]
    grid = [g for g in dict.fromkeys(grid + local) if math.isfinite(g[3])]
    preds: dict = {g: [] for g in grid}
    with single_thread_torch():
        _select(coords, folds, grid, target_db, phys_db, preds)
    names = {g: f"{g[0]} l={g[1]:.3g} deg, l_rho={g[2]:g}, eta={g[3]:g}" + (" (half-spacing)" if g in local else "")
             for g in preds}
    for g, pred in preds.items():
        errors[names[g]] = np.abs(np.concatenate(pred) - target_db[val_all])
    validated = {"physics only"} | {names[g] for g in preds if g not in local}
    chosen, _ = choose({k: v for k, v in errors.items() if k in validated})
    local_names = [names[g] for g in preds if g in local]
    if local_names:      # the half-spacing residual unless a validated one beats it (and the physics alone)
        best_local = min(local_names, key=lambda k: float(np.mean(errors[k])))
        if chosen == "physics only" or not beats(errors[chosen], errors[best_local]):
            chosen = best_local
    scores = {k: float(np.mean(v)) for k, v in errors.items()}
    out = ResidualFit("off", validation=scores, chosen=chosen, how=how)
    if chosen != "physics only":
        kind, ld, lr, eta = next(g for g, n in names.items() if n == chosen)
        _, params = kernel_predict(kind, coords, target_db, phys_db, _pick(coords, slice(0, 0)), phys_db[:0],
                                   math.radians(ld), lr, eta)
        out.form = kind
        out.params = dict(params, length_deg=ld, range_length=lr, weight=eta, floor_db=floor_db)
    out.wall_time_s = time.time() - t0
    return out


class _SurfelResidual:
    """The gaussian form on fixed training pairs: field = field_phys + sum_p term_p r_g(p)."""

    def __init__(self, pairs: PairGeometry, material_of_gaussian, mats: MaterialValues, gain_db: float,
                 num_gaussians: int):
        with torch.no_grad():
            self.field0, self.diffuse0 = scattered_field(pairs, material_of_gaussian, mats)
            self.terms, _ = specular_terms(pairs, material_of_gaussian, mats)
        self.link, self.gauss, self.num_g = pairs.link, pairs.gauss, num_gaussians
        self.gain = 10 ** (gain_db / 10)

    def db(self, r: torch.Tensor, floor: float) -> torch.Tensor:
        extra = torch.zeros_like(self.field0).index_add(0, self.link, self.terms * r[self.gauss][:, None])
        return 10 * torch.log10((abs2(self.field0 + extra) + self.diffuse0) * self.gain + floor)

    def fit(self, target_db: np.ndarray, rows: np.ndarray, lam: float, cfg: ResidualConfig) -> torch.Tensor:
        """r [G] complex minimising the dB MSE on `rows` + lam sum |r|^2 / (rows x frequencies)."""
        target = torch.as_tensor(target_db[rows])
        floor = float(10 ** ((float(target.min()) - 30.0) / 10))
        rows_t = torch.as_tensor(rows)
        re = torch.zeros(self.num_g, dtype=torch.float64, requires_grad=True)
        im = torch.zeros(self.num_g, dtype=torch.float64, requires_grad=True)
        opt = torch.optim.Adam([re, im], lr=cfg.lr)
        n = float(target.numel())
        for _ in range(cfg.iterations):
            opt.zero_grad()
            r = torch.complex(re, im)
            loss = ((self.db(r, floor)[rows_t] - target) ** 2).sum() / n + lam * (re**2 + im**2).sum() / n
            loss.backward()
            opt.step()
        return torch.complex(re, im).detach()


def fit_gaussian(pairs: PairGeometry, material_of_gaussian, mats: MaterialValues, gain_db: float, num_gaussians: int,
                 phys_db: np.ndarray, target_db: np.ndarray, folds: list[np.ndarray], cfg: ResidualConfig,
                 how: str) -> ResidualFit:
    """Choose lambda of the gaussian form by validation over `folds` (physics only among them) and
    fit it on every training row. pairs: those of the training links (rows of target_db [M, K])."""
    t0 = time.time()
    model = _SurfelResidual(pairs, material_of_gaussian, mats, gain_db, num_gaussians)
    m = len(target_db)
    if len(folds[0]) >= MIN_FOLD_LINKS:   # each fold costs a full fit: one fold when it is large enough
        folds = folds[:1]
    val_all = np.concatenate(folds)
    errors = {"physics only": np.abs(phys_db[val_all] - target_db[val_all])}
    lams = [x for x in ((cfg.weight,) if cfg.weight is not None else cfg.gaussian_weights) if math.isfinite(x)]
    for lam in lams:
        pred = []
        for val in folds:
            r = model.fit(target_db, np.setdiff1d(np.arange(m), val), lam, cfg)
            with torch.no_grad():
                pred.append(np.maximum(model.db(r, 0.0).numpy()[val], FLOOR_DB))
        errors[f"gaussian lambda={lam:g}"] = np.abs(np.concatenate(pred) - target_db[val_all])
    chosen, scores = choose(errors)
    out = ResidualFit("off", validation=scores, chosen=chosen, how=how)
    if chosen != "physics only":
        lam = lams[list(scores).index(chosen) - 1]
        out.form = "gaussian"
        out.params = {"weight": lam, "surfel": model.fit(target_db, np.arange(m), lam, cfg)}
    out.wall_time_s = time.time() - t0
    return out


# ----- the artifact -----

def floor_of(params: dict) -> np.ndarray:
    """The floor [F] dB under the physics of a kernel form's params (-inf, none, where not given)."""
    if "floor_db" in params:
        return np.asarray(params["floor_db"], float)
    return np.full(len(np.atleast_1d(params["mean_db"])), -np.inf)


def residual_fields(fit: ResidualFit, train_tx_m: np.ndarray, train_rx_m: np.ndarray) -> tuple[dict, dict]:
    """(datasets, model attributes) of a residual for the rf artifact (schema: residual/*)."""
    attrs = {"residual.form": fit.form, "residual.chosen": fit.chosen}
    data = {}
    if fit.form in ("smooth", "blend"):
        data = {"residual/tx_pos": np.asarray(train_tx_m, float), "residual/rx_pos": np.asarray(train_rx_m, float),
                "residual/weights_db": np.asarray(fit.params["weights_db"], float),
                "residual/mean_db": np.asarray(fit.params["mean_db"], float)}
        if "floor_db" in fit.params:     # a form fitted by fit_smooth; none on one made by hand
            data["residual/floor_db"] = floor_of(fit.params)
        attrs.update({"residual.length_deg": float(fit.params["length_deg"]),
                      "residual.range_length": float(fit.params["range_length"]),
                      "residual.weight": float(fit.params["weight"])})
    elif fit.form == "gaussian":
        r = fit.params["surfel"].numpy()
        data = {"residual/surfel": np.stack([r.real, r.imag], 1)}
        attrs["residual.weight"] = float(fit.params["weight"])
    return data, attrs


def load_residual(rf) -> ResidualFit:
    """The residual of an rf artifact (form "off" when it has none)."""
    attrs = rf.free.get("model@attrs", {})
    form = str(attrs.get("residual.form", "off"))
    if form in ("smooth", "blend"):
        return ResidualFit(form, {"tx_m": np.asarray(rf["residual/tx_pos"], float),
                                  "rx_m": np.asarray(rf["residual/rx_pos"], float),
                                  "weights_db": np.asarray(rf["residual/weights_db"], float),
                                  "mean_db": np.asarray(rf["residual/mean_db"], float),
                                  **({"floor_db": np.asarray(rf["residual/floor_db"], float)}   # schema >= 1.4
                                     if rf.get("residual/floor_db") is not None else {}),
                                  "length_deg": float(attrs["residual.length_deg"]),
                                  "range_length": float(attrs["residual.range_length"]),
                                  "weight": float(attrs["residual.weight"])}, chosen=str(attrs.get("residual.chosen", "")))
    if form == "gaussian":
        s = np.asarray(rf["residual/surfel"], float)
        return ResidualFit(form, {"surfel": torch.complex(torch.as_tensor(s[:, 0]), torch.as_tensor(s[:, 1])),
                                  "weight": float(attrs["residual.weight"])}, chosen=str(attrs.get("residual.chosen", "")))
    return ResidualFit("off")


def kernel_form_at(fit: ResidualFit, tx_m: np.ndarray, rx_m: np.ndarray, centre: np.ndarray, phys_db: np.ndarray,
                   freqs_hz: np.ndarray, fitted_hz: np.ndarray) -> tuple[np.ndarray, list]:
    """(prediction [L, K] dB of the smooth / blend form at links tx/rx [L, 3] and freqs [K], where the
    physics predicts phys_db [L, K]; the frequencies that were not fitted, where the physics stays)."""
    p = fit.params
    out = np.array(phys_db, dtype=float, copy=True)
    cols, missing = [], []
    for f in np.asarray(freqs_hz, float):
        hit = np.flatnonzero(np.abs(np.asarray(fitted_hz) - f) <= 1e-6 * f)
        cols.append(int(hit[0]) if hit.size else -1)
        if not hit.size:
            missing.append(f)
    have = [k for k, c in enumerate(cols) if c >= 0]
    if have:
        sel = [cols[k] for k in have]
        params = {"weights_db": p["weights_db"][:, sel], "mean_db": p["mean_db"][sel]}
        floored = np.maximum(out[:, have], floor_of(p)[sel][None])   # as the form was fitted
        out[:, have] = blend_at(fit.form, link_coords(p["tx_m"], p["rx_m"], centre), params,
                                link_coords(tx_m, rx_m, centre), floored, math.radians(p["length_deg"]),
                                p["range_length"], p["weight"])
    return out, missing
