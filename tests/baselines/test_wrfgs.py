"""WRF-GS-style baseline: the composite over the stored hit lists equals an independent brute-force
evaluation, gradients reach every part, a short fit beats the training mean, and the CLI writes its
results JSON for both tasks."""
import importlib.util
import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from rfir_core.artifacts import write_artifact
from rfir_stages.baselines.wrfgs import (WrfgsField, WrfgsSettings, cap_directions, composite_weights,
                                         predict_wrfgs, render_links, train_wrfgs)

ROOT = Path(__file__).resolve().parents[2]
TINY = dict(n_dirs=24, width=16, feat_dim=4, n_freqs_pos=2, n_freqs_dir=2, n_freqs_tx=2, alpha_min=1e-3)


@pytest.fixture(autouse=True)
def _one_thread():
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def _shell(n: int = 40, radius: float = 2.0, scale: float = 0.45, seed: int = 0):
    """n isotropic-ish Gaussians on a sphere around the origin (every ray from inside hits some)."""
    rng = np.random.default_rng(seed)
    i = np.arange(n) + 0.5
    z = 1 - 2 * i / n
    r = np.sqrt(1 - z * z)
    phi = math.pi * (3 - math.sqrt(5)) * i
    means = radius * np.stack([r * np.cos(phi), r * np.sin(phi), z], 1) + 0.05 * rng.normal(size=(n, 3))
    log_scales = np.log(scale * rng.uniform(0.6, 1.2, size=(n, 3)))
    q = rng.normal(size=(n, 4))
    return means, log_scales, q / np.linalg.norm(q, axis=1, keepdims=True)


def _rotmat(q):
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _brute_force(field: WrfgsField, geometry, origin, dirs, tx, alpha_min):
    """Complex received signal [2] of one receiver: for every ray and every Gaussian the peak response
    along the ray, hits sorted by t, T = prod (1 - alpha) of the earlier ones, signals from the MLP."""
    means, log_scales, rots = geometry
    sinv = [_rotmat(q) @ np.diag(np.exp(-2 * ls)) @ _rotmat(q).T for q, ls in zip(rots, log_scales)]
    opac = field.opacity().detach().double().numpy()
    with torch.no_grad():
        gcode = field.gaussian_code().double().numpy()
        txc = field.tx_code(torch.as_tensor(tx, dtype=torch.float32)[None])[0].double().numpy()
    total = np.zeros(2)
    for d in dirs:
        hits = []
        for g in range(len(means)):
            p = means[g] - origin
            sd = sinv[g] @ d
            t = sd @ p / (sd @ d)
            e = origin + t * d - means[g]
            G = math.exp(-0.5 * e @ sinv[g] @ e)
            if t > 0 and G >= alpha_min:
                hits.append((t, g, min(opac[g] * G, 0.99)))
        trans = 1.0
        with torch.no_grad():
            dc = field.dir_code(torch.as_tensor(d, dtype=torch.float32)[None])[0].double().numpy()
        for _, g, a in sorted(hits):
            h = torch.as_tensor(np.maximum(gcode[g] + txc + dc, 0.0), dtype=torch.float32)
            with torch.no_grad():
                s = field.head(h[None])[0].double().numpy()
            total += trans * a * s
            trans *= 1 - a
    return total


def test_composite_matches_brute_force_and_the_tracer():
    torch.manual_seed(0)
    geometry = _shell(12, radius=1.5, scale=0.4)
    s = WrfgsSettings(**TINY)
    field = WrfgsField(*geometry, ([0, 0, 0], 2.0), s)
    with torch.no_grad():   # varied opacities, so the transmittance matters
        field.opacity_logit.copy_(torch.linspace(-2.0, 3.0, 12))
    origins = np.array([[0.1, -0.2, 0.05], [0.4, 0.3, -0.3]])
    tx = np.array([[1.0, 0.5, 0.2], [-0.7, 0.2, 0.9]])
    hits = field.trace_receivers(origins)
    assert hits.num_hits > 20
    got = render_links(field, hits, torch.tensor([0, 1]), torch.as_tensor(tx, dtype=torch.float32),
                       return_complex=True).detach().double().numpy()
    for k in range(2):
        ref = _brute_force(field, geometry, origins[k], hits.dirs[k].double().numpy(), tx[k], s.alpha_min)
        np.testing.assert_allclose(got[k], ref, rtol=2e-4, atol=1e-6)
    # the per-ray weights agree with the tracer's own compositing (features = 1: sum of weights);
    # opacity 1, so that the tracer's alpha_min cut keeps the same hits as the stored lists
    import rfir_tracer

    ray_key = torch.repeat_interleave(torch.arange(2), hits.offsets[1:] - hits.offsets[:-1]) * s.n_dirs + hits.ray
    alpha = hits.response.clamp(max=0.99)
    w = composite_weights(alpha, ray_key)
    per_ray = torch.zeros(2 * s.n_dirs, dtype=torch.float64).index_add_(0, ray_key, w.double())
    o = torch.as_tensor(origins)[:, None].expand(-1, s.n_dirs, -1).reshape(-1, 3).contiguous()
    res = rfir_tracer.trace(field.tracer_scene(), o, hits.dirs.double().reshape(-1, 3).contiguous(),
                            features=torch.ones(12, 1, dtype=torch.float64),
                            alpha_min=s.alpha_min, t_stop=0.0)
    np.testing.assert_allclose(per_ray.numpy(), res.features[:, 0].numpy(), rtol=1e-4, atol=1e-6)


def test_cap_directions_stay_in_the_cone_and_gradients_reach_everything():
    axis = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, -2.0]], dtype=torch.float64)
    d = cap_directions(64, axis, torch.tensor([0.1, 0.3]))
    assert d.shape == (2, 64, 3)
    cosang = (d * (axis / axis.norm(dim=-1, keepdim=True))[:, None]).sum(-1)
    assert torch.allclose(d.norm(dim=-1), torch.ones(2, 64, dtype=torch.float64))
    assert (cosang[0] >= math.cos(0.1) - 1e-9).all() and (cosang[1] >= math.cos(0.3) - 1e-9).all()
    torch.manual_seed(0)
    field = WrfgsField(*_shell(), ([0, 0, 0], 2.5), WrfgsSettings(**TINY))
    hits = field.trace_receivers(np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.2]]))
    tx = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    y = render_links(field, hits, torch.tensor([0, 1]), tx)
    assert torch.isfinite(y).all()
    y.pow(2).mean().backward()
    for name, p in field.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name
    y2 = render_links(field, hits, torch.tensor([0, 0]), tx).detach()
    assert abs(float(y2[0] - y2[1])) > 1e-4           # the transmitter changes the prediction


def _links():
    """3 Tx x 36 Rx inside the shell; y = free-space loss at 2.4 GHz plus a Tx-dependent term, dB."""
    rng = np.random.default_rng(1)
    txs = np.array([[0.9, 0.0, 0.3], [-0.6, 0.7, -0.2], [0.0, -0.8, 0.6]])
    rxs = rng.uniform(-0.9, 0.9, size=(36, 3))
    tx, rx = np.repeat(txs, len(rxs), 0), np.tile(rxs, (len(txs), 1))
    d = np.linalg.norm(tx - rx, axis=1)
    y = 20 * np.log10(0.125 / (4 * math.pi * d)) + 3.0 * np.sign(tx[:, 0] + 0.1)
    return tx, rx, y


def test_short_training_beats_the_training_mean():
    tx, rx, y = _links()
    s = WrfgsSettings(**{**TINY, "width": 32, "feat_dim": 8}, epochs=60, batch_links=27, lr=1e-2, seed=0)
    seen = []
    field, hist = train_wrfgs(_shell(), tx, rx, y, np.arange(len(y)), s, progress=seen.append)
    assert len(seen) == 60 and hist["stopped_by"] == "epochs" and hist["num_hits"] > 0
    pred = predict_wrfgs(field, tx, rx)                     # traces the receivers again
    pred_cached = predict_wrfgs(field, tx, None, hits=field.hits, recv=field.link_receiver)
    np.testing.assert_allclose(pred, pred_cached, atol=1e-4)
    mae = np.mean(np.abs(pred - y))
    mean_mae = np.mean(np.abs(y.mean() - y))
    assert mean_mae > 3.0
    assert mae < 0.4 * mean_mae, (mae, mean_mae)


def test_wall_clock_budget_stops_training():
    tx, rx, y = _links()
    s = WrfgsSettings(**TINY, epochs=10_000, batch_links=16, minutes=0.01)
    _, hist = train_wrfgs(_shell(), tx, rx, y, np.arange(len(y)), s)
    assert hist["stopped_by"] == "time" and len(hist["epochs"]) < 10_000 and hist["wall_time_s"] < 10


def test_validation_keeps_the_best_epoch():
    tx, rx, y = _links()
    val, fit = np.arange(0, len(y), 6), np.setdiff1d(np.arange(len(y)), np.arange(0, len(y), 6))
    s = WrfgsSettings(**TINY, epochs=8, batch_links=16, lr=1e-2)
    field, hist = train_wrfgs(_shell(), tx, rx, y, fit, s, val_idx=val)
    maes = [e["mae_val_db"] for e in hist["epochs"]]
    assert hist["best_epoch"] == int(np.argmin(maes)) + 1 and hist["best_val_mae_db"] == min(maes)
    p = predict_wrfgs(field, tx[val], None, hits=field.hits, recv=field.link_receiver[val])
    assert abs(np.mean(np.abs(p - y[val])) - min(maes)) < 1e-4      # the kept parameters are the best epoch's


def _load_cli():
    spec = importlib.util.spec_from_file_location("baseline_wrfgs_cli", ROOT / "scripts" / "baseline_wrfgs.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _write_inputs(tmp_path: Path):
    means, log_scales, rots = _shell(30, radius=0.3, scale=0.08)
    normals = means / np.linalg.norm(means, axis=1, keepdims=True)
    scene = write_artifact(tmp_path / "scene.h5", "scene", {
        "gaussians/means": means, "gaussians/log_scales": log_scales, "gaussians/rotations": rots,
        "gaussians/opacities": np.ones(len(means)), "gaussians/normals": normals})
    # rcs: a radar on a 3 m circle around the shell, 2 degree steps
    asp = np.radians(np.arange(0.0, 360.0, 2.0))
    pos = np.stack([3 * np.cos(asp), 3 * np.sin(asp), np.zeros_like(asp)], 1)
    pg = (-60.0 + 5.0 * np.cos(3 * asp))[:, None]
    n = len(asp)
    rcs = write_artifact(tmp_path / "rcs.h5", "measurements", {
        "tx_pos": pos, "rx_pos": pos, "freq_hz": np.array([2.4e9]), "path_gain_db": pg,
        "channel": (10 ** (pg / 20)).astype(np.complex128), "split": (np.arange(n) % 2).astype(np.int64),
        "tx_id": np.arange(n), "rx_id": np.arange(n), "scene_bounds": np.array([[-0.5] * 3, [0.5] * 3]),
        "rcs_dbsm": pg + 30.0, "aspect_rad": asp, "range_m": np.full(n, 3.0)}, attrs={"task": "rcs", "scene": "toy"})
    # rssi: 20 Tx x 6 Rx near the shell
    rng = np.random.default_rng(2)
    txs, rxs = rng.uniform(-0.2, 0.2, size=(20, 3)), rng.uniform(-0.2, 0.2, size=(6, 3))
    tx, rx = np.repeat(txs, 6, 0), np.tile(rxs, (20, 1))
    y = (20 * np.log10(0.125 / (4 * math.pi * (np.linalg.norm(tx - rx, axis=1) + 0.1))))[:, None]
    m = len(tx)
    rssi = write_artifact(tmp_path / "rssi.h5", "measurements", {
        "tx_pos": tx, "rx_pos": rx, "freq_hz": np.array([2.4e9]), "path_gain_db": y,
        "channel": (10 ** (y / 20)).astype(np.complex128), "split": (np.arange(m) % 5 == 0).astype(np.int64),
        "tx_id": np.repeat(np.arange(20), 6), "rx_id": np.tile(np.arange(6), 20),
        "scene_bounds": np.array([[-0.5] * 3, [0.5] * 3])}, attrs={"task": "rssi", "scene": "toy"})
    return scene, rcs, rssi


KEYS = {"name", "task", "scene", "method", "measurements", "split", "seed", "metrics", "settings", "num_parameters",
        "train_time_s", "predict_time_s", "wall_time_s", "threads", "supports_edit", "edit_note"}


def test_cli_writes_the_results_json_for_both_tasks(tmp_path, capsys):
    cli = _load_cli()
    scene, rcs, rssi = _write_inputs(tmp_path)
    runs = [(rcs, ["--task", "rcs", "--protocol", "every-10"], "rcs", "every-10", 18, 162),
            (rssi, ["--task", "rssi", "--split", "holdout_tx"], "rssi", "holdout_tx", 96, 24),
            (rssi, ["--split", "random"], "rssi", "random", 96, 24)]
    for k, (meas, extra, task, split, n_train, n_test) in enumerate(runs):
        res = tmp_path / f"r{k}.json"
        cli.main([str(meas), "--scene", str(scene), *extra, "--results", str(res), "--quick", "--threads", "1"])
        out = json.loads(res.read_text())
        assert KEYS <= set(out), KEYS - set(out)
        assert out["task"] == task and out["split"] == split and out["supports_edit"] is False
        assert out["method"].startswith("wrfgs (")
        met = out["metrics"]
        assert {"mae_db", "mae_train_db", "num_train", "num_test", "split"} <= set(met)
        assert (met["num_train"], met["num_test"]) == (n_train, n_test)
        assert np.isfinite(met["mae_db"]) and np.isfinite(met["mae_train_db"]) and out["num_parameters"] > 0
        assert out["settings"]["rays"] == ("cone" if task == "rcs" else "sphere")
    assert "wrfgs rssi random: test MAE" in capsys.readouterr().out
