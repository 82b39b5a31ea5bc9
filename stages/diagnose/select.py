"""Which effect explains the residual: fit every candidate on the training rows, score it on the
held-out rows with a penalty for its parameters, name the best or none; add it and repeat.

Held-out gain of a candidate: per test row u_i = |r_i| - |r_i - c_i| (r: residual of the current
model, c: the candidate's correction); gain = mean u. A candidate is significant when
- its t statistic mean(u) / (std(u) / sqrt(n)) exceeds T_MIN (noise would not give it), and
- it removes at least MIN_REL of the current held-out MAE, and at least MIN_GAIN_DB (a real, not a
  cosmetic, improvement).
Among the significant ones the best score = gain - PARAM_PENALTY * MAE * (number of parameters)
is named. Confidence: the share of bootstrap resamples of the test rows in which the named effect
still has the best score and a positive gain.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .effects import BY_NAME, CATALOGUE, Effect
from .rows import Rows

T_MIN = 3.0
MIN_REL = 0.05
PARAM_PENALTY = 0.01
BOOTSTRAP = 300
MIN_CONFIDENCE = 0.5
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
    test_mae_db: float = float("nan")
    gain_db: float = float("nan")
    t_stat: float = float("nan")
    score: float = float("nan")
    significant: bool = False
    x: np.ndarray | None = None
    u: np.ndarray | None = None   # per test row improvement [dB]


def compose(chain: list[tuple[Effect, np.ndarray]], rows: Rows, base_db: np.ndarray | None = None) -> np.ndarray:
    """The model's prediction with the chain of effects applied in order [dB, N]."""
    out = rows.pred_db.copy() if base_db is None else base_db.copy()
    for eff, x in chain:
        out = out + eff.correction(x, rows, out)
    return out


def refit_chain(chain: list[tuple[Effect, np.ndarray]], rows: Rows, sweeps: int = 2) -> list[tuple[Effect, np.ndarray]]:
    """Refit every effect's parameters on the training rows with the others held, in order, `sweeps` times."""
    chain = list(chain)
    for _ in range(sweeps if len(chain) > 1 else 1):
        for i, (eff, _x) in enumerate(chain):
            before = compose(chain[:i], rows)
            x = eff.fit(rows, before, rows.train)
            chain[i] = (eff, x)
    return chain


def evaluate(rows: Rows, base_db: np.ndarray, exclude=()) -> list[Candidate]:
    """Fit and score every applicable candidate on top of base_db [dB, N]."""
    r = rows.meas_db - base_db
    test, train = rows.test, rows.train
    mae0 = float(np.mean(np.abs(r[test])))
    out = []
    for eff in CATALOGUE:
        ok, reason = eff.applies(rows)
        cand = Candidate(eff.name, eff.title, bool(ok), "" if ok else reason, num_params=len(eff.params))
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
        cand.x, cand.u, cand.params = x, u, eff.describe(x)
        cand.train_mae_db = float(np.mean(np.abs(new[train])))
        cand.test_mae_db = float(np.mean(np.abs(new[test])))
        cand.gain_db = float(np.mean(u))
        cand.t_stat = cand.gain_db / se if se > 0 else (float("inf") if cand.gain_db > 0 else 0.0)
        cand.score = cand.gain_db - PARAM_PENALTY * mae0 * cand.num_params
        cand.significant = bool(cand.t_stat > T_MIN and cand.gain_db >= max(MIN_REL * mae0, MIN_GAIN_DB))
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
        gains = {c.name: float(np.mean(c.u[idx])) - (c.gain_db - c.score) for c in scored}
        top = max(gains, key=gains.get)
        wins += top == best.name and gains[best.name] > 0
    return best, wins / BOOTSTRAP


def rivals(cands: list[Candidate], best: Candidate, share: float = 0.8) -> list[str]:
    """Consistent candidates whose held-out gain reaches `share` of the best one's (the ambiguity)."""
    return [c.name for c in cands if c.applies and c.u is not None and not c.reason and c.name != best.name
            and c.gain_db >= share * best.gain_db]


def chain_to_json(chain) -> list[dict]:
    return [{"effect": eff.name, "params": eff.describe(x), "x": [float(v) for v in x]} for eff, x in chain]


def chain_from_json(items: list[dict]) -> list[tuple[Effect, np.ndarray]]:
    out = []
    for item in items:
        if item["effect"] not in BY_NAME:
            raise ValueError(f"unknown effect {item['effect']!r} (known: {', '.join(BY_NAME)})")
        out.append((BY_NAME[item["effect"]], np.asarray(item["x"], float)))
    return out
