"""How well the training links determine each fitted material: a range of |Gamma| at normal incidence.

A material fitted from links that barely see it (a small weak object beside a metal one, a floor seen
only near grazing) can land anywhere within a wide set of materials that all explain the links about
as well; its fitted |Gamma(0)| alone reads as more certain than it is. For each material in turn, with
every other material held at its fitted value, the training loss is evaluated at a fixed grid of
physical materials (eps_r x sigma x slab thickness, the fitted S and S = 0). A candidate is compatible
with the links when its mean increase of the per-link squared dB error over the fitted state is within
`margin` standard errors of that increase (the one-standard-error rule of rfir_stages.model.residual:
a difference the links cannot resolve). Neighbouring links (the next aspect of a turntable, the next
receiver of a transmitter) err alike, so the standard error is that of the means of NUM_BLOCKS
contiguous blocks of training rows (batch means), not of independent links. The range is the span of
|Gamma(0)| over the compatible candidates and the fitted material (docs/physics.md section 8.12).

The grid is coarse by design (it is a profile with the other parameters of the material on a grid,
not re-optimised), so the range is a lower bound on the true indeterminacy: a material whose range is
wide is not determined by the links; a narrow range says the grid found no other material that fits.
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from rfir_core.physics.materials import METAL_SIGMA_S_PER_M
from rfir_core.progress import NullProgress
from rfir_core.threads import single_thread_torch

from .physical import THICKNESS_M, MaterialParams

# (params, material i) -> (rows [M_i] int64, params -> predicted dB [M_i, K] of those links): normal_reflection_ranges
LocalPredictor = Callable[[MaterialParams, int], tuple[torch.Tensor, Callable[[MaterialParams], torch.Tensor]]]

EPS_R_GRID = (1.5, 2.0, 3.0, 4.5, 7.0, 10.0, 15.0, 25.0)                 # up to EPS_R_MAX
SIGMA_1GHZ_GRID = (1e-3, 0.05, METAL_SIGMA_S_PER_M)               # S/m: a low-loss, a lossy dielectric, a metal
THICKNESS_GRID_M = (0.003, 0.006, 0.01, 0.02, 0.05, 0.1, 0.2)     # m, within THICKNESS_M
NUM_BLOCKS = 20   # batch means of the standard error: contiguous blocks of training rows
# A range of |Gamma(0)| wider than this is "not determined by the links". The ITU-R P.2040 building materials
# at 2.4 GHz and their typical thicknesses span 0.15-0.70 (ceiling board to glass; metal 1): a range wider
# than about half of that holds materials as unlike as wood (0.27) and marble (0.64), so the fitted value
# does not say what the material is.
WIDE_RANGE = 0.3
NOT_DETERMINED = "not determined by the links"


def range_note(low: float, high: float) -> str:
    """NOT_DETERMINED for a |Gamma(0)| range (low, high) wider than WIDE_RANGE, else ""."""
    return NOT_DETERMINED if float(high) - float(low) > WIDE_RANGE else ""


def block_standard_error(d: torch.Tensor, num_blocks: int = NUM_BLOCKS) -> float:
    """Standard error of mean(d) [M] from the means of num_blocks contiguous blocks (fewer when M is small)."""
    blocks = [b.mean() for b in torch.tensor_split(d, min(num_blocks, len(d)))]
    if len(blocks) < 2:
        return 0.0
    return float(torch.stack(blocks).std()) / np.sqrt(len(blocks))


def normal_reflection_ranges(predict_db: Callable[[MaterialParams], torch.Tensor], params: MaterialParams,
                             target_db: np.ndarray, freq_hz: float, margin: float = 1.0,
                             progress=None, local: LocalPredictor | None = None) -> np.ndarray:
    """[N, 2] (low, high) |Gamma| at normal incidence at freq_hz [Hz] of each of the N materials of
    `params` compatible with the training links (module docstring). predict_db(params) -> [M, K] dB
    predicted path gain of the training links (the fit's own prediction, floor included); target_db
    [M, K] measured dB. `params` is restored before returning. progress: a rfir_core.progress reporter.

    local(params, i) -> (rows [M_i] int64, predict_rows): the links whose prediction depends on material
    i and a function that gives predict_db(p)[rows] [M_i, K] dB for any p differing from `params` (as
    passed, the fitted state) in material i alone. With it, each grid point of material i costs the part
    of the prediction that involves material i (the other links' errors do not change: their d is 0);
    the ranges are those of predict_db alone, to rounding."""
    target = torch.as_tensor(np.asarray(target_db, dtype=np.float64))
    f = torch.tensor([float(freq_hz)], dtype=torch.float64)
    keep = {k: v.detach().clone() for k, v in params.state_dict().items()}
    thicknesses = (None,) if params.half_space else tuple(t for t in THICKNESS_GRID_M
                                                          if THICKNESS_M[0] <= t <= THICKNESS_M[1])
    progress = progress or NullProgress()
    grid = [(eps, sig, th) for eps in EPS_R_GRID for sig in SIGMA_1GHZ_GRID for th in thicknesses]
    fitted_s = params.values().scattering.detach().numpy().copy()
    # S 0 as well as the fitted S for each material's own S; a shared S stays as fitted
    variants = [sorted({float(s)} if params.shared_scattering else {float(s), 0.0}) for s in fitted_s]
    total = sum(len(v) for v in variants) * len(grid)
    with torch.no_grad(), single_thread_torch(), progress.task("material ranges", total=total) as bar:
        def error(pred: torch.Tensor, tgt: torch.Tensor) -> torch.Tensor:   # [M] squared dB error, mean over K
            return ((pred - tgt) ** 2).reshape(len(tgt), -1).mean(1)

        fitted = params.values().normal_reflection(f).abs()[:, 0].numpy()
        out = np.stack([fitted, fitted], 1)
        base = error(predict_db(params), target) if local is None else None
        for i in range(params.num):
            if local is not None:
                rows, predict_rows = local(params, i)
                at = target[rows]
                base_rows = error(predict_rows(params), at) if len(rows) else None
            for s in variants[i]:
                for eps, sig, th in grid:
                    params.set_values(i, eps_r=eps, sigma_1ghz=sig, scattering=s, thickness_m=th)
                    if local is None:
                        d = error(predict_db(params), target) - base
                    else:   # the links that do not see material i keep their error: d = 0
                        d = torch.zeros(len(target), dtype=torch.float64)
                        if len(rows):
                            d[rows] = error(predict_rows(params), at) - base_rows
                    if float(d.mean()) <= margin * block_standard_error(d):
                        g = float(params.values().normal_reflection(f).abs()[i, 0])
                        out[i] = min(out[i, 0], g), max(out[i, 1], g)
                    params.load_state_dict(keep)
                    bar.advance(1)
    return out
