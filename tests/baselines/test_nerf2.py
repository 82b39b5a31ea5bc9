"""NeRF2-style baseline: shapes, gradients, dependence on the transmitter, and a short fit to
free-space path loss that must beat predicting the training mean."""
import math

import numpy as np
import pytest
import torch

from rfir_stages.baselines.nerf2 import Nerf2Field, Nerf2Settings, fibonacci_sphere, predict_nerf2, render_links, train_nerf2

BOUNDS = np.array([[0.0, 0.0, 0.0], [4.0, 4.0, 2.0]])
TINY = dict(n_dirs=16, n_samples=8, width=32, feat_dim=16, att_layers=2, rad_layers=2)


@pytest.fixture(autouse=True)
def _one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _links():
    """4 Tx at 1.6 m height x a 6 x 6 Rx grid at 0.8 m: tx [144, 3], rx [144, 3], FSPL y [144] dB."""
    txs = np.array([[0.8, 0.8, 1.6], [3.2, 0.8, 1.6], [0.8, 3.2, 1.6], [3.2, 3.2, 1.6]])
    g = np.linspace(0.4, 3.6, 6)
    rxs = np.stack(np.meshgrid(g, g, indexing="ij"), -1).reshape(-1, 2)
    rxs = np.concatenate([rxs, np.full((len(rxs), 1), 0.8)], 1)
    tx = np.repeat(txs, len(rxs), 0)
    rx = np.tile(rxs, (len(txs), 1))
    lam = 3e8 / 2.4e9
    d = np.linalg.norm(tx - rx, axis=1)
    return tx, rx, 20 * np.log10(lam / (4 * math.pi * d))


def test_fibonacci_sphere_is_unit_and_balanced():
    d = fibonacci_sphere(64)
    assert d.shape == (64, 3)
    assert torch.allclose(d.norm(dim=1), torch.ones(64), atol=1e-5)
    assert d.mean(0).abs().max() < 0.05


def test_render_shapes_finite_and_stratified():
    torch.manual_seed(0)
    f = Nerf2Field(BOUNDS, Nerf2Settings(**TINY))
    tx = torch.tensor([[1.0, 1.0, 1.5], [3.0, 2.0, 1.5], [2.0, 3.0, 1.0]])
    rx = torch.tensor([[2.0, 2.0, 0.5], [0.5, 0.5, 0.5], [3.9, 3.9, 1.9]])
    y = render_links(f, tx, rx)
    ys = render_links(f, tx, rx, stratified=True, generator=torch.Generator().manual_seed(1))
    assert y.shape == (3,) and ys.shape == (3,)
    assert torch.isfinite(y).all() and torch.isfinite(ys).all()
    assert not torch.allclose(y, ys)                       # stratified sampling moves the samples
    p = predict_nerf2(f, tx.numpy(), rx.numpy(), batch=2)
    np.testing.assert_allclose(p, y.detach().numpy(), rtol=1e-5, atol=1e-4)


def test_gradients_reach_both_networks_and_the_offset():
    torch.manual_seed(0)
    f = Nerf2Field(BOUNDS, Nerf2Settings(**TINY))
    tx = torch.tensor([[1.0, 1.0, 1.5], [3.0, 2.0, 1.5]])
    rx = torch.tensor([[2.0, 2.0, 0.5], [0.5, 0.5, 0.5]])
    render_links(f, tx, rx).pow(2).mean().backward()
    for name, mod in [("att", f.att), ("rad", f.rad), ("rad_tx", f.rad_tx), ("rad_dir", f.rad_dir), ("rad_feat", f.rad_feat)]:
        g = sum(p.grad.abs().sum() for p in mod.parameters() if p.grad is not None)
        assert g > 0, name
    assert f.offset_db.grad is not None and f.offset_db.grad.abs() > 0


def test_transmitter_position_changes_the_prediction():
    torch.manual_seed(0)
    f = Nerf2Field(BOUNDS, Nerf2Settings(**TINY))
    rx = torch.tensor([[2.0, 2.0, 0.8]]).repeat(2, 1)
    tx = torch.tensor([[0.5, 0.5, 1.6], [3.5, 3.0, 1.6]])
    y = render_links(f, tx, rx).detach()
    assert abs(float(y[0] - y[1])) > 1e-3


def test_short_training_beats_the_training_mean_on_free_space_loss():
    tx, rx, y = _links()
    rng = np.random.default_rng(0)
    perm = rng.permutation(len(y))
    test, train = perm[:30], perm[30:]
    s = Nerf2Settings(**TINY, epochs=40, batch_links=16, lr=5e-3, seed=0)
    seen = []
    field, hist = train_nerf2(tx, rx, y, train, s, progress=seen.append, bounds=BOUNDS)
    assert len(seen) == 40 and hist["stopped_by"] == "epochs"
    pred = predict_nerf2(field, tx, rx)
    mae = np.mean(np.abs(pred[test] - y[test]))
    mean_mae = np.mean(np.abs(y[train].mean() - y[test]))
    assert mean_mae > 2.0
    assert mae < 0.5 * mean_mae, (mae, mean_mae)
    assert hist["epochs"][-1]["loss"] < 0.3 * hist["epochs"][0]["loss"]


def test_wall_clock_budget_stops_training():
    tx, rx, y = _links()
    s = Nerf2Settings(**TINY, epochs=1000, batch_links=16, minutes=0.02)
    _, hist = train_nerf2(tx, rx, y, np.arange(len(y)), s, bounds=BOUNDS)
    assert hist["stopped_by"] == "time" and len(hist["epochs"]) < 1000
    assert hist["wall_time_s"] < 10
