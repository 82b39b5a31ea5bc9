"""Which pairs of photos structure from motion matches: what `calibrate.sfm.matcher = "auto"` resolves to.

Matching every pair costs n^2/2 pairs; photos taken along a path (a walk through a room, a video's frames) need
only each photo against its neighbours in name order, a few jumps, and a check for places the path comes back
to: about n (overlap + log2 n) pairs plus a few dozen (120 photos: 1,994 pairs with the defaults instead of
7,140). Whether the photos are such a sequence is
probed, not assumed: a few neighbouring pairs (i, i+1) and a few far pairs (i, i + about n/2) are matched on a
small feature budget, and the verified inliers compared. Photos named in the order they were taken share most of
their view with their neighbours and little with far ones; photos in any other order (a set gathered from
several walks, names from another sort) look at their neighbours as at any other photo. The photos are a
sequence when at least 3 in 4 neighbouring pairs verify (probe_min_inliers or more) and their median inlier count
is at least probe_near_far_ratio times the far pairs'. Up to exhaustive_max_images photos every pair is matched
anyway: the saving would be small (sequential matching's pairs equal exhaustive's at about 2 (overlap + log2 n)
photos) and nothing needs assuming about the order.

Sequential matching closes loops without a vocabulary tree (COLMAP's loop detection needs one, a download): every
loop_closure_period-th photo is a keyframe, and the keyframes are matched among themselves, so a path that comes
back to a place (the walk round a room that ends where it began) is tied together there. When sequential matching
chosen by the probe registers fewer than sequential_min_registered_fraction of the photos, the caller matches
again exhaustively (`fallback`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NEIGHBOUR_SHARE = 0.75     # of the neighbouring pairs that must verify: one gap in four (a turn, a blurred photo) is allowed


@dataclass
class MatcherChoice:
    """What the matcher setting resolved to: matcher ("exhaustive", "sequential", "spatial"), SIFT features per photo,
    the reason (one line, printed), and probed: chosen by the sequence probe (so a poor registration falls back to
    exhaustive matching)."""
    matcher: str
    num_features: int
    reason: str
    probed: bool = False


@dataclass
class SequenceProbe:
    """Verified inliers [K] of the neighbouring pairs (i, i+1) and [K] of the far pairs the probe matched."""
    near: np.ndarray
    far: np.ndarray


def probe_pairs(n: int, count: int, seed: int = 0) -> tuple[list[tuple[int, int]], list[tuple[int, int]]]:
    """(neighbouring pairs, far pairs) of photo indices 0..n-1 in name order: count pairs (i, i+1) with i spread
    evenly over the sequence, and count pairs (i, j) with i random and j about n/2 further on round the sequence
    (between n/4 and 3n/4 apart, so that a loop's end does not count as far from its start)."""
    count = max(1, min(count, n - 1))
    starts = np.unique(np.linspace(0, n - 2, count).round().astype(int))
    near = [(int(i), int(i) + 1) for i in starts]
    rng = np.random.default_rng(seed)
    far = []
    for i in rng.choice(n, size=min(count, n), replace=False):
        j = (int(i) + int(rng.integers(n // 4, max(n // 4 + 1, 3 * n // 4 + 1)))) % n
        if j != i:
            far.append((min(int(i), j), max(int(i), j)))
    return near, sorted(set(far))


def is_sequence(probe: SequenceProbe, min_inliers: int, near_far_ratio: float) -> tuple[bool, str]:
    """(whether the probed photos are a sequence, the reason in words) by the rule of the module docstring."""
    near_ok = int((probe.near >= min_inliers).sum())
    near_med = float(np.median(probe.near)) if len(probe.near) else 0.0
    far_med = float(np.median(probe.far)) if len(probe.far) else 0.0
    facts = (f"{near_ok} of {len(probe.near)} neighbouring pairs verify, median {near_med:.0f} inliers; "
             f"far pairs median {far_med:.0f}")
    if near_ok < NEIGHBOUR_SHARE * len(probe.near):
        return False, f"not a sequence: {facts} (neighbours do not overlap)"
    if near_med < near_far_ratio * max(far_med, 1.0):
        return False, f"not a sequence: {facts} (far pairs overlap as much: the names do not follow the path)"
    return True, f"a sequence: {facts}"


def loop_pairs(n: int, period: int, overlap: int) -> list[tuple[int, int]]:
    """Keyframe pairs for loop closure: every period-th photo (and the last) against each other, less the pairs
    sequential matching already makes (fewer than overlap apart, or a power of two apart: its quadratic jumps).
    period 0: none."""
    if period <= 0 or n < 3:
        return []
    keys = sorted(set(range(0, n, period)) | {n - 1})
    out = []
    for a, i in enumerate(keys):
        for j in keys[a + 1:]:
            gap = j - i
            if gap > overlap and gap & (gap - 1) != 0:
                out.append((i, j))
    return out


def choose(options, n_images: int, base: tuple[str, int], probe=None) -> MatcherChoice:
    """The matcher for n_images photos under `options` (SfmOptions). base: (matcher, features) of the rule without
    a probe (sfm.choose_matcher: a named matcher, or "auto" by the number of photos); probe: a callable (near pairs,
    far pairs) -> SequenceProbe that matches those pairs on the small feature budget (sfm.probe_inliers), called
    only when "auto" has more than exhaustive_max_images photos to match."""
    matcher, features = base
    if options.matcher != "auto":
        return MatcherChoice(matcher, features, f"calibrate.sfm.matcher = {options.matcher!r}")
    if n_images <= options.exhaustive_max_images or probe is None:
        return MatcherChoice(matcher, features, f"{n_images} photos: every pair (up to {options.exhaustive_max_images} "
                                                "photos nothing is assumed about their order)")
    near, far = probe_pairs(n_images, options.probe_pairs, options.seed)
    sequence, why = is_sequence(probe(near, far), options.probe_min_inliers, options.probe_near_far_ratio)
    if sequence:
        return MatcherChoice("sequential", options.max_num_features,
                             f"{why}: each photo against its {options.sequential_overlap} next, with loop closure",
                             probed=True)
    return MatcherChoice(matcher, features, f"{why}: {_describe(matcher, features, n_images)}")


def fallback(options, n_images: int, all_centres_known: bool, registered: int) -> MatcherChoice:
    """The matcher after sequential matching registered only `registered` of n_images photos: every pair (with the
    reduced feature budget above exhaustive_max_images photos), or spatial from the known centres above
    reduced_exhaustive_max_images photos."""
    if n_images > options.reduced_exhaustive_max_images and all_centres_known:
        matcher, features = "spatial", options.max_num_features
    elif n_images <= options.exhaustive_max_images:
        matcher, features = "exhaustive", options.max_num_features
    else:
        matcher, features = "exhaustive", min(options.max_num_features, options.reduced_num_features)
    return MatcherChoice(matcher, features,
                         f"sequential matching registered {registered} of {n_images} photos (below "
                         f"{options.sequential_min_registered_fraction:.0%}): {_describe(matcher, features, n_images)}")


def _describe(matcher: str, features: int, n_images: int) -> str:
    if matcher == "exhaustive":
        return f"every pair of the {n_images} photos, {features} features each"
    if matcher == "spatial":
        return "each photo against the photos nearest its known centre"
    return "sequential all the same (every pair of so many photos would take hours; name them in capture order)"
