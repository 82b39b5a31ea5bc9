"""Which residual terms a room fit gets (rf_fit.room.residual_terms; the terms: model/residual_terms.py):
chosen by validation on the training links' residuals after the physical fit, never on test rows.

The roaming side's positions (the side with more distinct positions, as device_choice.held_out_rows picks it) are
split into FOLDS folds drawn with the seed; each fold in turn is held out, the terms fitted on the other links'
residuals and scored on it, so every training link is scored once, at a position the terms did not see (the
fixed devices, the anchors, are shared, as at prediction). Candidates in a fixed order, each hyper-parameter
(pattern prior, cell size, field smoothness, kriging length and nugget) taken at its lowest held-out MAE:
off, patterns, field, patterns + field (fitted jointly, with their own best settings), scored on held-out areas
(whole k-means blocks of roaming positions: these terms must carry where the survey did not reach), then kriging of
what the best of those leaves, scored on held-out positions. A candidate replaces the one chosen so far only where
it lowers the held-out MAE by MARGIN_DB; a field must also be no worse on held-out fixed devices (all links of a
fifth of the anchors held out; patterns and kriging do not apply to them), since a field that stands for the
fitted anchors' own structure does not carry to another one. A list ("field+kriging") takes those terms, their
settings still chosen by validation.
The physical fit saw the held-out links too: it has a few material parameters, the terms hundreds, so the
scores rank the terms; they are not a test error.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rfir_stages.model.device_gains import SIDES, device_index, gains_at
from rfir_stages.model.fit_physical import training_predictor
from rfir_stages.model.residual_terms import (TERMS, FloorGrid, ResidualTerms, exponential_kernel, fit_kriging,
                                              fit_linear, pattern_design, pattern_features)

FOLDS = 5
MARGIN_DB = 0.05               # a candidate must lower the held-out MAE by this over the one chosen before it
MIN_DEVICE_LINKS = 30          # a fixed device gets a pattern and kriging with at least this many training links
MIN_LINKS = 50                 # fewer training links: no terms (the choice would be noise)
PATTERN_PRIORS_DB = (1.0, 3.0)
CELL_SIZES_M = (0.5, 1.0)
FIELD_PRIOR_DB_PER_M = 1.0
SMOOTH_PRIORS_DB_PER_M = (0.1, 0.3, 1.0)
KRIGING_LENGTHS_M = (0.5, 1.0, 2.0, 4.0)
NUGGET_SHARES = (0.3, 0.6)
MAX_KRIGING_POINTS = 2000      # per device, evenly thinned: the kernel solve grows as the cube


@dataclass
class ResidualChoice:
    """The terms chosen (None: off), their names joined by " + " ("off"), why, the held-out MAE [dB] of each
    candidate."""

    terms: ResidualTerms | None
    which: str
    reason: str
    scores: dict = field(default_factory=dict)


def parse_request(value: str) -> tuple[str, ...] | None:
    """rf_fit.room.residual_terms as the terms asked for: None for "auto", () for "off", else the names joined
    by "+"; ValueError naming the unknown one."""
    value = str(value).strip()
    if value == "auto":
        return None
    if value == "off":
        return ()
    names = tuple(n.strip() for n in value.split("+"))
    bad = [n for n in names if n not in TERMS]
    if bad or not names:
        raise ValueError(f"{bad[0] if bad else value!r} is not a residual term: expected \"auto\", \"off\" or terms "
                         f"of {', '.join(TERMS)} joined by '+'")
    return tuple(n for n in TERMS if n in names)


class _Survey:
    """The training links as the terms see them: fixed and roaming ends, each link's fixed device (-1: none), the
    pattern rows, the folds of the roaming positions."""

    def __init__(self, tx_m, rx_m, ids: dict, residual_db, floor_lo_xy, floor_hi_xy, seed: int):
        tx, rx = np.asarray(tx_m, np.float64), np.asarray(rx_m, np.float64)
        ends = {"tx": tx, "rx": rx}
        counts = {s: len(device_index(p)[0]) for s, p in ends.items()}
        self.roam = "rx" if counts["rx"] >= counts["tx"] else "tx"
        self.side = "tx" if self.roam == "rx" else "rx"
        self.fixed, self.other = ends[self.side], ends[self.roam]
        self.r = np.asarray(residual_db, np.float64)
        _, inv, pos = device_index(self.fixed, ids.get(self.side))
        n = np.bincount(inv, minlength=len(pos))
        keep = np.flatnonzero(np.isfinite(pos).all(1) & (n >= MIN_DEVICE_LINKS))
        remap = np.full(len(pos), -1)
        remap[keep] = np.arange(len(keep))
        self.device, self.device_pos = remap[inv], pos[keep]
        features = pattern_features(self.fixed, self.other)
        self.pattern_rows = {el: pattern_design(self.device, features * [1, 1, 1, 1, el], len(keep))
                             for el in (0, 1)} if len(keep) else None
        _, where, positions = device_index(self.other)
        rng = np.random.default_rng(seed)
        self.num_positions = len(positions)
        self.folds = {"positions": rng.permutation(self.num_positions)[where] % FOLDS,
                      "areas": spatial_blocks(positions[:, :2], rng)[where]}
        if len(keep) >= 2:   # whole fixed devices held out (-1: a link without one, never held out)
            groups = np.append(rng.permutation(len(keep)) % min(FOLDS, len(keep)), -1)
            self.folds["devices"] = groups[self.device]
        ends_xy = np.concatenate([tx[:, :2], rx[:, :2]])
        self.lo = np.minimum(np.asarray(floor_lo_xy, np.float64), ends_xy.min(0))
        self.hi = np.maximum(np.asarray(floor_hi_xy, np.float64), ends_xy.max(0))
        self._lengths: dict = {}

    def lengths(self, cell_m: float):
        """(grid, W [M, C]) of cells of cell_m over the floor plan and the links' ends, computed once per size."""
        if cell_m not in self._lengths:
            grid = FloorGrid.covering(self.lo, self.hi, cell_m)
            self._lengths[cell_m] = (grid, grid.lengths(self.fixed, self.other))
        return self._lengths[cell_m]

    def linear(self, rows, settings: dict):
        """fit_linear on the links `rows` with settings {"patterns": prior dB or None, "elevation": 0 or 1,
        "cell": m or None, "smooth": dB/m}; returns a function: links -> the terms' sum [K] dB."""
        p = None if settings.get("patterns") is None else self.pattern_rows[settings["elevation"]]
        grid, w = (None, None) if settings.get("cell") is None else self.lengths(settings["cell"])
        a, x = fit_linear(self.r[rows], None if p is None else p[rows], None if w is None else w[rows], grid,
                          pattern_prior_db=settings.get("patterns") or 1.0, field_prior_db_per_m=FIELD_PRIOR_DB_PER_M,
                          smooth_prior_db_per_m=settings.get("smooth", 0.3))
        return lambda at: (0 if a is None else p[at] @ a) - (0 if x is None else w[at] @ x)

    def cross_validate(self, settings: dict, folds: str) -> tuple[np.ndarray, list]:
        """(held-out prediction [M] dB of every link, [FOLDS] in-fold prediction functions) of the linear terms,
        folds: "positions" or "areas"."""
        out, fits = np.zeros(len(self.r)), []
        fold = self.folds[folds]
        for k in range(FOLDS):
            train, held = np.flatnonzero(fold != k), np.flatnonzero(fold == k)
            if not len(held):
                fits.append(None)
                continue
            f = self.linear(train, settings)
            out[held] = f(held)
            fits.append(f)
        return out, fits

    def krige(self, rows, residual_db, length_m: float, nugget: float):
        """Per-device kriging fitted on `rows` of residual_db [M]: (device [T], points [T, 3], weights [T])."""
        devs, pts, wts = [], [], []
        for d in range(len(self.device_pos)):
            mine = rows[self.device[rows] == d]
            if len(mine) > MAX_KRIGING_POINTS:
                mine = mine[np.linspace(0, len(mine) - 1, MAX_KRIGING_POINTS).round().astype(np.int64)]
            if len(mine) < 2:
                continue
            devs.append(np.full(len(mine), d))
            pts.append(self.other[mine])
            wts.append(fit_kriging(self.other[mine], residual_db[mine], length_m, nugget))
        if not devs:
            return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0)
        return np.concatenate(devs), np.concatenate(pts), np.concatenate(wts)

    def kriged(self, at, fitted, length_m: float) -> np.ndarray:
        """The kriged residual [K] dB at links `at` from krige's (device, points, weights)."""
        dev, pts, wts = fitted
        out = np.zeros(len(at))
        for d in np.unique(dev):
            sel = self.device[at] == d
            if sel.any():
                out[sel] = exponential_kernel(self.other[at[sel]], pts[dev == d], length_m) @ wts[dev == d]
        return out


def _mae(x: np.ndarray) -> float:
    return float(np.abs(x).mean())


def spatial_blocks(points_xy: np.ndarray, rng, per_fold: int = 3) -> np.ndarray:
    """Fold [P] of each roaming position [P, 2] m: the positions grouped into FOLDS x per_fold compact areas
    (k-means, 20 rounds from positions drawn with rng), whole areas dealt to the folds at random."""
    pts = np.asarray(points_xy, np.float64)
    k = min(FOLDS * per_fold, len(pts))
    centres = pts[rng.choice(len(pts), k, replace=False)]
    for _ in range(20):
        label = ((pts[:, None] - centres[None]) ** 2).sum(-1).argmin(1)
        centres = np.stack([pts[label == c].mean(0) if (label == c).any() else centres[c] for c in range(k)])
    return rng.permutation(k)[label] % FOLDS


def choose_residual_terms(tx_m, rx_m, ids: dict, residual_db, floor_lo_xy, floor_hi_xy, seed: int,
                          request: str = "auto") -> ResidualChoice:
    """The residual terms of training links tx_m, rx_m [M, 3] m with residuals residual_db [M] dB (measured minus
    the fitted physical model), over the floor rectangle floor_lo_xy .. floor_hi_xy [2] m; ids {side: [M] or None}
    the file's device ids; request: rf_fit.room.residual_terms (parse_request)."""
    wanted = parse_request(request)
    if wanted == ():
        return ResidualChoice(None, "off", "rf_fit.room.residual_terms = \"off\"")
    s = _Survey(tx_m, rx_m, {k: ids.get(k) for k in SIDES}, residual_db, floor_lo_xy, floor_hi_xy, seed)
    if len(s.r) < MIN_LINKS or s.num_positions < FOLDS * 3:
        return ResidualChoice(None, "off", f"too few training links ({len(s.r)}) or {s.roam} positions "
                                           f"({s.num_positions}) to validate residual terms; "
                                           "rf_fit.room.residual_terms sets them")
    allowed = set(TERMS if wanted is None else wanted)
    if s.pattern_rows is None:
        allowed -= {"patterns", "kriging"}
    scores, settings = {"off": _mae(s.r)}, {"off": {}}

    def best_of(name: str, grid: list[dict]):
        results = [(cfg, _mae(s.r - s.cross_validate(cfg, "areas")[0])) for cfg in grid]
        settings[name], scores[name] = min(results, key=lambda t: t[1])
        if "devices" in s.folds:
            held = s.folds["devices"] >= 0
            devices[name] = _mae((s.r - s.cross_validate(settings[name], "devices")[0])[held])

    devices = {}
    if "devices" in s.folds:
        devices["off"] = _mae(s.r[s.folds["devices"] >= 0])

    # the terms that must carry to places the survey did not reach: scored on held-out areas
    if "patterns" in allowed:
        best_of("patterns", [{"patterns": p, "elevation": e} for p in PATTERN_PRIORS_DB for e in (0, 1)])
    if "field" in allowed:
        best_of("field", [{"cell": c, "smooth": q} for c in CELL_SIZES_M for q in SMOOTH_PRIORS_DB_PER_M])
    if {"patterns", "field"} <= allowed:
        best_of("patterns + field", [{**settings["patterns"], **settings["field"]}])
    if wanted is None:
        base = "off"
        for name in ("patterns", "field", "patterns + field"):
            # better on held-out areas, and no worse on held-out fixed devices (where only the field applies):
            # a field that stands for the fitted devices' own structure does not carry to another device
            if name in scores and scores[name] < scores[base] - MARGIN_DB and \
                    devices.get(name, 0.0) <= devices.get(base, 0.0):
                base = name
    else:
        base = " + ".join(n for n in ("patterns", "field") if n in allowed) or "off"
    near = {}
    if "kriging" in allowed:
        # kriging interpolates between surveyed positions and reverts to the rest away from them: scored on held-out
        # positions, against the terms chosen above on the same folds
        pred, fits = s.cross_validate(settings[base], "positions") if base != "off" else (0.0, None)
        near[base] = _mae(s.r - pred)
        fold, trials = s.folds["positions"], {}
        for length in KRIGING_LENGTHS_M:
            for nugget in NUGGET_SHARES:
                out = np.zeros(len(s.r))
                for k in range(FOLDS):
                    train, rows = np.flatnonzero(fold != k), np.flatnonzero(fold == k)
                    rest = s.r - (0 if fits is None else fits[k](np.arange(len(s.r))))
                    out[rows] = s.kriged(rows, s.krige(train, rest, length, nugget), length)
                trials[(length, nugget)] = _mae(s.r - pred - out)
        (length, nugget), score = min(trials.items(), key=lambda t: t[1])
        name = "kriging" if base == "off" else f"{base} + kriging"
        near[name], settings[name] = score, {**settings[base], "length": length, "nugget": nugget}
        if wanted is not None or score < near[base] - MARGIN_DB:
            base = name
    terms = None if base == "off" else _final(s, settings[base])
    cfg = settings[base]
    words = ([f"pattern prior {cfg['patterns']:g} dB{'' if cfg['elevation'] else ', azimuth only'}"]
             if cfg.get("patterns") else []) + \
        ([f"field cells {cfg['cell']:g} m, smoothness prior {cfg['smooth']:g} dB/m"] if cfg.get("cell") else []) + \
        ([f"kriging length {cfg['length']:g} m, nugget {cfg['nugget']:.0%}"] if cfg.get("length") else [])
    shown = ", ".join(f"{k} {v:.2f}" for k, v in scores.items())
    if devices:
        shown += "; on held-out fixed devices: " + ", ".join(f"{k} {v:.2f}" for k, v in devices.items())
    if near:
        shown += "; on held-out positions: " + ", ".join(f"{k} {v:.2f}" for k, v in near.items())
    reason = ((f"auto: validated on {len(s.r)} training links in {FOLDS} folds of their {s.num_positions} {s.roam} "
               f"positions, each term over the simpler by at least {MARGIN_DB:g} dB"
               if wanted is None else f"rf_fit.room.residual_terms = \"{request}\", settings validated on "
                                      f"{len(s.r)} training links")
              + f" (MAE dB on held-out areas: {shown})" + ("; " + "; ".join(words) if words else "")
              + ("; rf_fit.room.residual_terms sets them" if wanted is None else ""))
    return ResidualChoice(terms, base.replace(" ", ""), reason, {**scores, **near})


def _final(s: _Survey, cfg: dict) -> ResidualTerms:
    """The terms of settings `cfg` fitted on every training link."""
    rows = np.arange(len(s.r))
    terms = ResidualTerms(s.side, s.device_pos)
    rest = s.r
    if cfg.get("patterns") or cfg.get("cell"):
        p = s.pattern_rows[cfg["elevation"]] if cfg.get("patterns") else None
        grid, w = (None, None) if not cfg.get("cell") else s.lengths(cfg["cell"])
        a, x = fit_linear(s.r, p, w, grid, pattern_prior_db=cfg.get("patterns") or 1.0,
                          field_prior_db_per_m=FIELD_PRIOR_DB_PER_M, smooth_prior_db_per_m=cfg.get("smooth", 0.3))
        if a is not None:
            terms.pattern = a.reshape(len(s.device_pos), -1)
            rest = rest - p @ a
        if x is not None:
            terms.grid, terms.field_db_per_m = grid, x
            rest = rest + w @ x
    if cfg.get("length"):
        terms.kriging_device, terms.kriging_pos_m, terms.kriging_weight_db = s.krige(rows, rest, cfg["length"],
                                                                                     cfg["nugget"])
        terms.kriging_length_m = float(cfg["length"])
    return terms


def training_residuals(links, room, params, devices, tx_m, rx_m, fit, target_db, freq_hz: float, band: str,
                       chunk_links: int = 512, axes=None) -> np.ndarray:
    """measured - physical [M] dB of every training link tx_m, rx_m [M, 3] m (target_db [M] dB) with the fitted
    materials `params` and device gains `devices` (centred, as stored): the fit links `fit` [K] from their traced
    `links`, the others traced here, chunk_links at a time (their antenna axes the rows of `axes`, a LinkAxes of
    the M links; None: each end's own)."""
    import torch

    target = np.asarray(target_db, np.float64)
    pred = np.empty(len(target))
    with torch.no_grad():
        pred[fit] = training_predictor(links, torch.as_tensor(target[fit, None]), devices)(params)[:, 0].numpy()
        rest = np.setdiff1d(np.arange(len(target)), fit)
        table = {} if devices is None else devices.table()
        for lo in range(0, len(rest), chunk_links):
            rows = rest[lo:lo + chunk_links]
            traced = room.band_links(tx_m[rows], rx_m[rows], freq_hz, band, axes=None if axes is None else axes.rows(rows))
            pred[rows] = training_predictor(traced, torch.as_tensor(target[rows, None]))(params)[:, 0].numpy() \
                + gains_at(table, tx_m[rows], rx_m[rows])[0]
    return target - pred


def clutter_map(terms: ResidualTerms, wall_xy_m: np.ndarray, path) -> None:
    """A PNG at `path`: the clutter field [dB/m] over the floor (cells no training link crosses left blank), the
    floor plan's walls (wall_xy_m [K, 2] m: the vertical surfels' centres) over it, the fixed devices marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    grid = terms.grid
    values = np.ma.masked_equal(terms.field_db_per_m.reshape(grid.shape), 0.0).T
    hi = grid.origin_m + np.asarray(grid.shape) * grid.cell_m
    lim = max(float(np.abs(values).max()) if values.count() else 0.0, 1e-3)
    fig, ax = plt.subplots(figsize=(7, 7 * (hi[1] - grid.origin_m[1]) / max(hi[0] - grid.origin_m[0], 1e-9) + 0.8))
    im = ax.imshow(values, origin="lower", extent=(grid.origin_m[0], hi[0], grid.origin_m[1], hi[1]),
                   cmap="RdBu_r", vmin=-lim, vmax=lim, interpolation="nearest")
    ax.scatter(wall_xy_m[:, 0], wall_xy_m[:, 1], s=1, c="k", label="walls (floor plan)")
    ax.scatter(terms.device_pos_m[:, 0], terms.device_pos_m[:, 1], marker="^", s=40, c="gold", edgecolors="k",
               label=f"fixed devices ({terms.side})")
    fig.colorbar(im, ax=ax, label="excess loss along the link [dB/m] (red: missing clutter)")
    ax.set(xlabel="x [m]", ylabel="y [m]", title=f"rfir clutter field ({grid.cell_m:g} m cells)")
    ax.legend(loc="upper right", fontsize=7)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
