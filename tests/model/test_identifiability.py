"""Ranges of |Gamma(0)| the training links allow (rfir_stages.model.identifiability)."""
import numpy as np
import torch

from rfir_stages.model.identifiability import block_standard_error, normal_reflection_ranges
from rfir_stages.model.physical import MaterialParams

F = 2.4e9


def _setup(noise_db: float, num_links: int, seed: int = 0):
    """Two materials; only material 0 reaches the links: pred_m = 10 log10(|Gamma_0(0)|^2 a_m) [dB]."""
    a = torch.linspace(1.0, 4.0, num_links, dtype=torch.float64)
    f = torch.tensor([F], dtype=torch.float64)

    def predict_db(params: MaterialParams) -> torch.Tensor:
        g = params.values().normal_reflection(f).abs()[0, 0]
        return (10 * torch.log10(g ** 2 * a))[:, None]

    params = MaterialParams(2, eps_r=4.5, sigma_1ghz=0.001, scattering=0.0, thickness_m=0.2)
    with torch.no_grad():
        target = predict_db(params).numpy() + np.random.default_rng(seed).normal(0, noise_db, (num_links, 1))
    return predict_db, params, target


def test_exact_links_pin_the_seen_material_and_leave_the_unseen_one_free():
    predict_db, params, target = _setup(0.0, 200)
    fitted = float(params.values().normal_reflection(torch.tensor([F], dtype=torch.float64)).abs()[0, 0])
    span = normal_reflection_ranges(predict_db, params, target, F)
    assert span.shape == (2, 2)
    assert span[0, 0] <= fitted <= span[0, 1] and span[0, 1] - span[0, 0] < 0.02   # every other |Gamma| costs
    assert span[1, 0] < 0.1 and span[1, 1] > 0.95          # no link sees it: anything from air-like to metal
    after = float(params.values().normal_reflection(torch.tensor([F], dtype=torch.float64)).abs()[0, 0])
    assert after == fitted                                  # the fitted state is restored


def test_noisy_links_widen_the_range_of_the_seen_material():
    exact = normal_reflection_ranges(*_setup(0.0, 20), F)[0]
    noisy = normal_reflection_ranges(*_setup(6.0, 20), F)[0]
    assert noisy[1] - noisy[0] > exact[1] - exact[0] + 0.05
    assert noisy[0] <= exact[0] and noisy[1] >= exact[1]


def test_block_standard_error_is_that_of_the_block_means():
    means = torch.tensor([0.0, 1.0, -1.0, 2.0], dtype=torch.float64)
    d = means.repeat_interleave(50)                          # 200 links, 4 blocks of identical values
    assert np.isclose(block_standard_error(d, 4), float(means.std()) / 2.0)
    # correlated links: the per-link standard error would be sqrt(200 / 4) times smaller
    assert block_standard_error(d, 4) > 5 * float(d.std()) / np.sqrt(len(d))
    assert block_standard_error(torch.ones(1, dtype=torch.float64)) == 0.0
