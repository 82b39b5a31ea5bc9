"""The residual's choice by validation (rfir_stages.model.residual.choose): the one-standard-error rule."""
import numpy as np

from rfir_stages.model.residual import SE_MARGIN, choose


def _errors(gain_in_se: float, n: int = 400, seed: int = 0) -> dict:
    """Validation errors where the candidate beats the physics by gain_in_se standard errors of the paired
    difference (the difference's sample mean and deviation set exactly)."""
    rng = np.random.default_rng(seed)
    phys = np.abs(rng.normal(2.0, 1.0, n))
    noise = rng.normal(0.0, 1.0, n)
    noise = (noise - noise.mean()) / noise.std(ddof=1)            # mean 0, sample deviation 1
    diff = noise - gain_in_se / np.sqrt(n)                        # mean = -gain_in_se standard errors
    return {"physics only": phys, "smooth l=2 deg": phys + diff}


def test_a_residual_that_beats_the_physics_by_more_than_the_margin_is_chosen():
    chosen, scores = choose(_errors(SE_MARGIN + 0.3))
    assert chosen == "smooth l=2 deg" and scores["smooth l=2 deg"] < scores["physics only"]


def test_a_residual_within_the_margin_leaves_the_physics_alone():
    chosen, scores = choose(_errors(SE_MARGIN - 0.3))
    assert chosen == "physics only" and scores["smooth l=2 deg"] < scores["physics only"]   # lower, not enough


def test_a_worse_residual_is_never_chosen():
    assert choose(_errors(-3.0))[0] == "physics only"
