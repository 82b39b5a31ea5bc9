"""The physical model on a band of frequencies (docs/physics.md; use: docs/guide/rcs-sweep.md).

Frequency is an input of the physical model (physical.py): the material laws give each frequency
its Fresnel coefficients, the geometry its phases and footprints. A band (e.g. 2000 frequencies
over 160 MHz) needs no other model, only bounded memory:
- fitting: the materials are fitted on `fit_columns` (evenly spaced frequencies of the band, both
  edges included); the aggregated sums (AggregatedPairs) are built in pair chunks of
  `aggregate_chunk` pairs so that a chunk holds about BUDGET complex values;
- prediction: the geometry of a block of links is traced once for every frequency. Up to
  EXACT_MAX_FREQS frequencies, the exact pair sum is evaluated in frequency chunks of about BUDGET
  (pair, frequency) values (`band_field`); more frequencies (a band) use the fit's aggregated form
  (`band_power`: Gamma on 2-degree incidence-angle nodes, the weakest 1 % of double-bounce cells
  dropped), faster than the exact sum; tests/model/test_physical.py holds that form to the pair sum.
Everything physical is imported from physical.py: this module only slices and loops.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import torch

from .physical import AggregatedPairs, MaterialValues, PairGeometry, scattered_field

BUDGET = 1 << 21    # complex values per chunk (32 MiB each; a chunk's temporaries are about ten of them)
EXACT_MAX_FREQS = 16   # more frequencies than this are predicted with the aggregated form (band_power)


def fit_columns(num_freqs: int, fit_freqs: int) -> np.ndarray:
    """Indices of `fit_freqs` evenly spaced frequencies of a band of `num_freqs` (both edges included;
    all of them when fit_freqs >= num_freqs)."""
    if fit_freqs >= num_freqs:
        return np.arange(num_freqs)
    return np.unique(np.linspace(0, num_freqs - 1, max(int(fit_freqs), 1)).round().astype(np.int64))


def aggregate_chunk(num_freqs: int, budget: int = BUDGET) -> int:
    """Pairs per chunk when aggregating pairs at num_freqs frequencies (AggregatedPairs.build)."""
    return max(1024, budget // max(int(num_freqs), 1))


def at_columns(pairs: PairGeometry, a: int, b: int) -> PairGeometry:
    """The same pairs restricted to frequencies a..b-1 (the double bounces' and edge waves' coefficients too)."""
    db = pairs.double
    if db is not None:
        db = dataclasses.replace(db, coef=db.coef[:, a:b], freq_hz=db.freq_hz[a:b])
    return dataclasses.replace(pairs, freq_hz=pairs.freq_hz[a:b], double=db,
                               edges=None if pairs.edges is None else pairs.edges.at_columns(a, b))


def _items(pairs: PairGeometry) -> int:
    """Terms per frequency column: the surfel pairs and the double-, triple-bounce and edge-wave items (what a
    chunk's memory grows with)."""
    return pairs.num_pairs + sum(0 if x is None else x.num for x in (pairs.double, pairs.triple, pairs.edges))


def band_field(pairs: PairGeometry, material_of_gaussian: torch.Tensor, mats: MaterialValues,
               surfel_factor: torch.Tensor | None = None, budget: int | None = None
               ) -> tuple[torch.Tensor, torch.Tensor]:
    """(coherent field [M, K] complex, diffuse power [M, K]) of physical.scattered_field at the pairs'
    K frequencies, evaluated in frequency chunks of about `budget` (default BUDGET) (pair, frequency) values."""
    budget = budget or BUDGET
    k = int(pairs.freq_hz.numel())
    items = _items(pairs)
    step = max(1, budget // max(items, 1))
    if step >= k:
        return scattered_field(pairs, material_of_gaussian, mats, surfel_factor=surfel_factor)
    field = torch.zeros((pairs.num_links, k), dtype=torch.complex128)
    diffuse = torch.zeros((pairs.num_links, k), dtype=torch.float64)
    for a in range(0, k, step):
        b = min(k, a + step)
        field[:, a:b], diffuse[:, a:b] = scattered_field(at_columns(pairs, a, b), material_of_gaussian, mats,
                                                         surfel_factor=surfel_factor)
    return field, diffuse


def band_power(pairs: PairGeometry, material_of_gaussian: torch.Tensor, mats: MaterialValues,
               budget: int | None = None) -> torch.Tensor:
    """Received power [M, K] (P_T = 1 W, no system gain) at the pairs' K frequencies with the fit's
    aggregated form (physical.AggregatedPairs), built and evaluated in frequency chunks."""
    budget = budget or BUDGET
    k = int(pairs.freq_hz.numel())
    n = int(mats.eps_r.numel())
    items = _items(pairs)
    step = max(1, min(k, 4 * budget // max(items, 1)))     # the aggregation streams pairs: its chunks bound memory
    out = torch.zeros((pairs.num_links, k), dtype=torch.float64)
    for a in range(0, k, step):
        b = min(k, a + step)
        agg = AggregatedPairs.build(at_columns(pairs, a, b), material_of_gaussian, n, chunk=aggregate_chunk(b - a, budget))
        out[:, a:b] = agg.power(mats)
    return out
