"""Which effect explains the residual: fit every candidate on the training rows, score it on the
held-out rows with a penalty for its parameters, name the best or none; add it and repeat.

Held-out gain of a candidate: per test row u_i = |r_i| - |r_i - c_i| (r: residual of the current
model, c: the candidate's correction); gain = mean u. A candidate is significant when
- its t statistic mean(u) / (std(u) / sqrt(n)) exceeds T_MIN (noise would not give it), and
- it removes at least MIN_REL of the current held-out MAE, and at least MIN_GAIN_DB (a real, not a
  cosmetic, improvement).
- its held-out information criterion improves: score = 2 n ln(MAE_before / MAE_after) - 2 k on the
  n held-out rows (Laplace likelihood of the residual, k fitted parameters; an AIC scored on rows
  the fit never saw), so a flexible effect (a box, one offset per device) cannot win by fitting noise.
Among the significant ones the best score is named. Confidence: the share of bootstrap resamples of
the test rows in which the named effect still has the best score and a positive gain.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from .effect_base import Effect
from .effects import BY_NAME, CATALOGUE
from .rows import Rows

T_MIN = 3.0
MIN_REL = 0.05
BOOTSTRAP = 300
MIN_CONFIDENCE = 0.5
RESOLUTION_DB = 0.01   # no measurement resolves a smaller MAE: exact fits tie there and the simpler effect wins
MIN_GAIN_DB = 0.05   # below any real measurement's noise: a gain this small is no effect


@dataclass
class Candidate:
    name: str
    title: str
    applies: bool
    reason: str = ""
    params: dict = field(default_factory=dict)
    num_params: int = 0
    train_mae_db: float = float("nan")
    mae_before_db: float = float("nan")   # held-out MAE of the model it extends
    test_mae_db: float = float("nan")
    gain_db: float = float("nan")
    t_stat: float = float("nan")
    score: float = float("nan")
    significant: bool = False
    x: np.ndarray | None = None
    u: np.ndarray | None = None   # per test row improvement [dB]
    abs_before: np.ndarray | None = None   # per test row |residual| before [dB]


def info_score(abs_before: np.ndarray, u: np.ndarray, k: int) -> float:
    """Held-out information criterion gain 2 n ln(MAE_before / MAE_after) - 2 k (module docstring)."""
    before = max(float(np.mean(abs_before)), RESOLUTION_DB)
    after = max(before - float(np.mean(u)), RESOLUTION_DB)
    return 2 * len(u) * float(np.log(before / after)) - 2 * k


def compose(chain: list[tuple[Effect, np.ndarray]], rows: Rows, base_db: np.ndarray | None = None) -> np.ndarray:
    """The model's prediction with the chain of effects applied in order [dB, N]."""
    out = rows.pred_db.copy() if base_db is None else base_db.copy()
    for eff, x in chain:
        out = out + eff.correction(x, rows, out)
    return out


def refit_chain(chain: list[tuple[Effect, np.ndarray]], rows: Rows, sweeps: int = 2,
                base_db: np.ndarray | None = None) -> list[tuple[Effect, np.ndarray]]:
    """Refit every effect's parameters on the training rows with the others held (block coordinate
    descent: effect i explains the measurement less what the later effects add), in order, `sweeps` times
    (on top of base_db [dB, N], default the model's prediction)."""
    chain = list(chain)
    for _ in range(sweeps if len(chain) > 1 else 1):
        for i, (eff, x_i) in enumerate(chain):
            before = compose(chain[:i], rows, base_db)
            later = compose(chain, rows, base_db) - before - eff.correction(x_i, rows, before)
            target = copy.copy(rows)            # what this effect must explain: the later effects held
            target.meas_db = rows.meas_db - later
            chain[i] = (eff, eff.fit(target, before, rows.train))
    return _joint_polish(chain, rows, base_db)


def _joint_polish(chain: list[tuple[Effect, np.ndarray]], rows: Rows, base_db: np.ndarray | None) -> list:
    """All effects fitted by plain least squares (no grid search of their own) refined together: block
    descent crawls when two effects trade off (a gain under a noise floor)."""
    smooth = [i for i, (eff, _x) in enumerate(chain) if type(eff).fit is Effect.fit]
    if len(smooth) < 2:
        return chain
    sizes = [len(chain[i][1]) for i in smooth]
    lo = np.concatenate([chain[i][0].lower or [-np.inf] * n for i, n in zip(smooth, sizes)])
    hi = np.concatenate([chain[i][0].upper or [np.inf] * n for i, n in zip(smooth, sizes)])
    x0 = np.clip(np.concatenate([chain[i][1] for i in smooth]), lo + 1e-9, hi - 1e-9)

    def unpack(x):
        out, k = list(chain), 0
        for i, n in zip(smooth, sizes):
            out[i] = (chain[i][0], x[k:k + n])
            k += n
        return out

    sol = least_squares(lambda x: (rows.meas_db - compose(unpack(x), rows, base_db))[rows.train], x0,
                        bounds=(lo, hi), loss="soft_l1", f_scale=1.0, max_nfev=300)
    return unpack(sol.x)


def evaluate(rows: Rows, base_db: np.ndarray, exclude=()) -> list[Candidate]:
    """Fit and score every applicable candidate on top of base_db [dB, N]."""
    r = rows.meas_db - base_db
    test, train = rows.test, rows.train
    mae0 = float(np.mean(np.abs(r[test])))
    out = []
    for eff in CATALOGUE:
        ok, reason = eff.applies(rows)
        cand = Candidate(eff.name, eff.title, bool(ok), "" if ok else reason, num_params=len(eff.params),
                         mae_before_db=mae0)
        if eff.name in exclude:
            cand.applies, cand.reason = False, "already in the model"
        if not cand.applies:
            out.append(cand)
            continue
        x = eff.fit(rows, base_db, train)
        c = eff.correction(x, rows, base_db)
        new = r - c
        u = np.abs(r[test]) - np.abs(new[test])
        se = float(np.std(u, ddof=1) / np.sqrt(max(len(u), 2))) if len(u) > 1 else float("inf")
        cand.x, cand.u, cand.params, cand.abs_before = x, u, eff.describe(x), np.abs(r[test])
        cand.num_params = eff.num_free(x)
        cand.train_mae_db = float(np.mean(np.abs(new[train])))
        cand.test_mae_db = float(np.mean(np.abs(new[test])))
        cand.gain_db = float(np.mean(u))
        cand.t_stat = cand.gain_db / se if se > 0 else (float("inf") if cand.gain_db > 0 else 0.0)
        cand.score = info_score(cand.abs_before, u, cand.num_params)
        cand.significant = bool(cand.t_stat > T_MIN and cand.gain_db >= max(MIN_REL * mae0, MIN_GAIN_DB)
                                and cand.score > 0)
        ok, why = eff.consistent(x, rows, train)
        if not ok:
            cand.significant, cand.reason = False, why
        out.append(cand)
    return out


def choose(cands: list[Candidate], seed: int = 0) -> tuple[Candidate | None, float]:
    """The best significant candidate (None: no significant missing effect) and its bootstrap confidence;
    the caller names it only when the confidence reaches MIN_CONFIDENCE."""
    sig = [c for c in cands if c.applies and c.significant]
    if not sig:
        return None, 0.0
    best = max(sig, key=lambda c: c.score)
    scored = [c for c in cands if c.applies and c.u is not None and not c.reason]   # consistent ones compete
    n = len(best.u)
    rng = np.random.default_rng(seed)
    wins = 0
    for _ in range(BOOTSTRAP):
        idx = rng.integers(0, n, n)
        gains = {c.name: info_score(c.abs_before[idx], c.u[idx], c.num_params) for c in scored}
        top = max(gains, key=gains.get)
        wins += top == best.name and gains[best.name] > 0
    return best, wins / BOOTSTRAP


def rivals(cands: list[Candidate], best: Candidate, share: float = 0.8) -> list[str]:
    """Consistent candidates whose held-out score reaches `share` of the best one's (the ambiguity)."""
    return [c.name for c in cands if c.applies and c.u is not None and not c.reason and c.name != best.name
            and c.score >= share * best.score]


def chain_to_json(chain) -> list[dict]:
    return [{"effect": eff.name, "params": eff.describe(x), "x": [float(v) for v in x]} for eff, x in chain]


def chain_from_json(items: list[dict]) -> list[tuple[Effect, np.ndarray]]:
    out = []
    for item in items:
        if item["effect"] not in BY_NAME:
            raise ValueError(f"unknown effect {item['effect']!r} (known: {', '.join(BY_NAME)})")
        out.append((BY_NAME[item["effect"]], np.asarray(item["x"], float)))
    return out


PAIR_TOP = 5   # pairs are tried among this many best-scoring single candidates
PAIR_SWEEPS = 1   # block sweeps per pair before the joint polish (the singles start them close)


@dataclass
class Pair:
    """Two effects fitted together (a combination the greedy search would miss: each alone is a poor
    stand-in, e.g. a gain plus a noise floor read as a path-loss slope)."""
    names: tuple
    chain: list
    gain_db: float
    score: float
    t_vs_single: float   # t statistic of the pair's held-out improvement over the best single candidate
    test_mae_db: float


def best_pair(rows: Rows, base_db: np.ndarray, cands: list[Candidate]) -> Pair | None:
    """The pair of catalogue effects (each among the PAIR_TOP best singles or a one-parameter effect:
    alone it may not help at all) that beats the best single
    candidate on held-out rows, with a better information score and t > T_MIN; None when none does."""
    usable = sorted([c for c in cands if c.applies and c.u is not None and not c.reason], key=lambda c: -c.score)
    top = [c for c in usable[:PAIR_TOP] if c.score > 0]
    if not top:
        return None
    partners = top + [c for c in usable[PAIR_TOP:] if c.num_params == 1]   # one-parameter partners are cheap
    single = top[0]
    r = rows.meas_db - base_db
    test = rows.test
    best = None
    for i, a in enumerate(partners):
        for b in partners[i + 1:]:
            chain = refit_chain([(BY_NAME[a.name], a.x), (BY_NAME[b.name], b.x)], rows, sweeps=PAIR_SWEEPS, base_db=base_db)
            c = compose(chain, rows, base_db) - base_db
            u = np.abs(r[test]) - np.abs(r[test] - c[test])
            k = sum(e.num_free(x) for e, x in chain)
            score = info_score(np.abs(r[test]), u, k)
            d = u - single.u
            se = float(np.std(d, ddof=1) / np.sqrt(len(d)))
            t = float(np.mean(d) / se) if se > 0 else 0.0
            if score > single.score and t > T_MIN and (best is None or score > best.score):
                best = Pair((a.name, b.name), chain, float(np.mean(u)), score, t,
                            float(np.mean(np.abs(r[test] - c[test]))))
    return best


def _mae(rows: Rows, pred: np.ndarray, mask: np.ndarray) -> float:
    return float(np.mean(np.abs(rows.meas_db[mask] - pred[mask])))


def cand_json(c: Candidate) -> dict:
    d = {"effect": c.name, "applies": c.applies}
    if not c.applies:
        d["reason"] = c.reason
        return d
    d.update(params=c.params, num_params=c.num_params, note=c.reason, test_mae_before_db=c.mae_before_db,
             test_mae_db=c.test_mae_db, gain_db=c.gain_db, t_stat=c.t_stat, score=c.score, significant=c.significant)
    return d


def search(rows: Rows, max_effects: int = 4, seed: int = 0, advance=None) -> tuple[list, list, list, list]:
    """Name, add and refit effects until none is significant (or max_effects): at each step the best
    single candidate, or the best pair when two effects fitted together beat it (best_pair).
    Returns (chain [(Effect, x)], steps [dict per step], named [dict per effect], ambiguous [names])."""
    chain, steps, named, ambiguous = [], [], [], []
    current = rows.pred_db.copy()
    while len(chain) < max_effects:
        cands = evaluate(rows, current, exclude={e.name for e, _ in chain})
        best, conf = choose(cands, seed)
        pair = best_pair(rows, current, cands) if best is not None and len(chain) + 2 <= max_effects else None
        record = {"step": len(steps) + 1, "test_mae_before_db": _mae(rows, current, rows.test),
                  "train_mae_before_db": _mae(rows, current, rows.train),
                  "candidates": [cand_json(c) for c in cands], "named": None}
        if pair is not None:
            record["pair"] = {"effects": list(pair.names), "score": pair.score, "t_vs_single": pair.t_vs_single,
                              "test_mae_db": pair.test_mae_db}
            added = [(e, x) for e, x in pair.chain]
            conf = max(conf, pair_confidence(pair))
        elif best is not None and conf < MIN_CONFIDENCE:
            record["ambiguous"] = [best.name] + rivals(cands, best)
            record["confidence"] = conf
            ambiguous = record["ambiguous"]
            best = None
        if best is not None:
            trial = compose(pair.chain, rows, current) if pair is not None else \
                current + BY_NAME[best.name].correction(best.x, rows, current)
            stand_in = not_reproduced(rows, current, trial)
            if stand_in is not None:
                record["not_reproduced"] = {**stand_in, "candidate": " + ".join(pair.names) if pair else best.name}
                best = None
        if best is None:
            steps.append(record)
            break
        if pair is None:
            added = [(BY_NAME[best.name], best.x)]
        chain = refit_chain(chain + added, rows, sweeps=3)
        current = compose(chain, rows)
        record.update(named=" + ".join(e.name for e, _ in added), confidence=conf,
                      params={k: v for e, x in chain[-len(added):] for k, v in e.describe(x).items()},
                      test_mae_after_db=_mae(rows, current, rows.test),
                      train_mae_after_db=_mae(rows, current, rows.train))
        steps.append(record)
        named += [{"effect": e.name, "title": e.title, "confidence": conf} for e, _ in added]
        if advance is not None:
            advance(len(added))
    for item, (eff, x) in zip(named, chain):
        item["params"] = eff.describe(x)
    return chain, steps, named, ambiguous


def pair_confidence(pair: Pair) -> float:
    """A pair is named with the one-sided normal confidence of its t statistic over the best single."""
    from scipy.stats import norm

    return float(norm.cdf(pair.t_vs_single))


REPRODUCE_SHARE = 0.9   # a named effect must explain this share of what the best breakdown explains
STRUCTURE_SHARE = 0.1   # ... unless that structure is smaller than this share of what the effect removes


def not_reproduced(rows: Rows, base_db: np.ndarray, trial_db: np.ndarray) -> dict | None:
    """When a breakdown explains a large share of the held-out residual (R^2 > LARGE_R2) and the
    candidate's prediction trial_db [dB, N] explains less than REPRODUCE_SHARE of that share, the
    candidate is a stand-in for structure the catalogue lacks: {axis, feature, r2_breakdown,
    r2_candidate}; else None. Both R^2 are on the held-out rows against the training rows' mean.
    Structure smaller (in squared dB) than STRUCTURE_SHARE of what the candidate removes is not
    counted: it is the model's own error beside a gap the candidate closes."""
    from .breakdown import AXIS, LARGE_R2, _heldout_r2, features

    r = rows.meas_db - base_db
    top, top_r2 = None, -np.inf
    for name, (bins, labels) in features(rows).items():
        r2 = _heldout_r2(r, bins, rows.train, rows.test, len(labels))
        if r2 > top_r2:
            top, top_r2 = name, r2
    if top is None or top_r2 <= LARGE_R2:
        return None
    test = rows.test
    sse0 = float(np.sum((r[test] - np.mean(r[rows.train])) ** 2))
    sse_trial = float(np.sum((rows.meas_db - trial_db)[test] ** 2))
    r2c = 1.0 - sse_trial / sse0 if sse0 > 0 else 0.0
    if r2c >= REPRODUCE_SHARE * top_r2:
        return None
    # R^2 is against the mean, so a gap that is mostly a constant leaves the model's own small errors as
    # the "structure": a breakdown that explains a tenth of a dB^2 does not make a stand-in of an
    # effect that removes a gap of several dB (squares summed about zero, held-out rows)
    removed = float(np.sum(r[test] ** 2)) - sse_trial
    if top_r2 * sse0 < STRUCTURE_SHARE * removed:
        return None
    return {"axis": AXIS.get(top, top), "feature": top, "r2_breakdown": float(top_r2), "r2_candidate": float(r2c)}
