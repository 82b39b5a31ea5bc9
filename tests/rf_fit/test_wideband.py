"""Wideband model (docs/physics.md section 7): each frequency's own k, the modulation network, the fitted band.

Synthetic target: two small metal-like squares 0.3 m apart along the line of sight, so the
two-way path difference is ~0.6 m and the spectrum ripples with period c / 0.6 m = 500 MHz.
"""
import json
import math

import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from rfir_cli.artifacts import read_artifact, write_artifact
from rfir_cli.physics.closed_forms import C0, rcs_from_path_gain
from rfir_stages.geom import gaussians_from_mesh, write_scene_artifact
from rfir_stages.rf_fit.antennas import AntennaPattern
from rfir_stages.rf_fit.links import radar_links, scene_centre
from rfir_stages.rf_fit.render import Materials, RenderSettings, build_cache, render
from rfir_stages.rf_fit.wideband import WidebandModel, pairs_from_cache
from rfir_stages.rf_fit.wideband_fit import WidebandConfig, fit_wideband

from .helpers import DEG, geometry, radar, square
from .test_stage import _app

ISO = AntennaPattern("isotropic")
FREQS = np.linspace(5.0e9, 6.0e9, 101)
SEP_M = 0.3


def _two_squares() -> dict:
    """Two 4 cm squares facing +x at x = +-SEP_M / 2, offset in y so neither hides the other."""
    parts = []
    for x, y in ((SEP_M / 2, 0.1), (-SEP_M / 2, -0.1)):
        v, f = square(0.04, x)
        parts.append(gaussians_from_mesh(v + np.array([0.0, y, 0.0]), f, 0.02))
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


def _truth_db(geom, links_fn, gamma_a) -> np.ndarray:
    """Path gain [M, K] dB of the renderer with |Gamma| gamma_a(f) on the front square, 0.4 behind."""
    front = geom.means[:, 0] > 0
    out = []
    for f in FREQS:
        cache = build_cache(geom, links_fn([f]), ISO, ISO, None, RenderSettings(visibility=False))
        g = torch.where(front, gamma_a(f), 0.4).to(torch.complex128)
        m = Materials(torch.full((geom.num,), 0.9, dtype=torch.float64),
                      torch.full((geom.num,), 3.0, dtype=torch.float64), g)
        out.append(10 * np.log10(np.abs(render(cache, m).numpy()[:, 0]) ** 2))
    return np.stack(out, 1)


def _setup():
    fields = _two_squares()
    geom = geometry(fields)
    aspects = np.arange(-6, 7, 1.0) * DEG

    def links_fn(freqs):
        return radar(aspects, 3.0, freqs)

    cache = build_cache(geom, links_fn(FREQS[:1]), ISO, ISO, None, RenderSettings(visibility=False))
    return geom, links_fn, pairs_from_cache(cache)


def _fit(geom, pairs, target, train, net_iterations=0, base_iterations=150):
    model = WidebandModel(torch.arange(geom.num), FREQS[train].min(), FREQS[train].max(), knots=5,
                          net={"embed_dim": 4, "hidden": 32, "layers": 3, "fourier": 3})
    cfg = WidebandConfig(base_iterations=base_iterations, net_iterations=net_iterations, freqs_per_step=16,
                         knots=5, net_lr=0.01)
    res = fit_wideband(model, pairs, FREQS[train], target[:, train], cfg, lr=0.05, s_tx_lr=0.5)
    return model, res


def test_ripple_period_reproduced_at_held_out_frequencies():
    geom, links_fn, pairs = _setup()
    target = _truth_db(geom, links_fn, lambda f: 0.9)
    assert np.ptp(target[6]) > 5.0  # the data ripple (else the test could not fail)
    train, test = np.arange(0, 101, 2), np.arange(1, 101, 2)
    model, res = _fit(geom, pairs, target, train)
    with torch.no_grad():
        pred = model.predict_db(pairs, torch.as_tensor(FREQS)).numpy()
    held_out = np.abs(pred[:, test] - target[:, test]).mean()
    flat = np.abs(target[:, test] - target[:, test].mean(1, keepdims=True)).mean()
    assert held_out < 0.3 < flat, (held_out, flat)
    # ripple period at aspect 0: spacing of the spectrum's minima = c / (two-way path difference)
    row = pred[6]
    minima = np.flatnonzero((row[1:-1] < row[:-2]) & (row[1:-1] < row[2:])) + 1
    assert len(minima) >= 2
    period = np.diff(FREQS[minima]).mean()
    assert abs(period - C0 / (2 * SEP_M)) < 0.05 * C0 / (2 * SEP_M), period


def test_network_off_is_the_base_renderer_exactly():
    geom, links_fn, pairs = _setup()
    model = WidebandModel(torch.arange(geom.num), FREQS[0], FREQS[-1], knots=3)
    with torch.no_grad():
        model.base.theta_g.copy_(torch.linspace(-1, 2, geom.num, dtype=torch.float64))
        model.base.theta_phi.copy_(torch.linspace(-3, 3, geom.num, dtype=torch.float64))
        model.net.linears[-1].weight.normal_()
    f = torch.as_tensor(FREQS[::10])
    cache = build_cache(geom, links_fn(FREQS[::10]), ISO, ISO, None, RenderSettings(visibility=False))
    ref = render(cache, model.base.materials())
    model.use_network = False
    assert torch.allclose(model.field(pairs, f), ref, rtol=1e-10, atol=1e-14)
    model.use_network = True  # a trained (here: random) network changes the result
    assert not torch.allclose(model.field(pairs, f), ref, rtol=1e-3)
    fresh = WidebandModel(torch.arange(geom.num), FREQS[0], FREQS[-1], knots=3)
    fresh.base.load_state_dict(model.base.state_dict())
    assert fresh.use_network and torch.allclose(fresh.field(pairs, f), ref, rtol=1e-10, atol=1e-14)  # zero last layer


def test_network_learns_a_frequency_dependent_reflection():
    geom, links_fn, pairs = _setup()
    target = _truth_db(geom, links_fn, lambda f: 0.95 - 0.8 * (f - FREQS[0]) / (FREQS[-1] - FREQS[0]))
    train, test = np.arange(0, 101, 2), np.arange(1, 101, 2)
    model, res = _fit(geom, pairs, target, train, net_iterations=300)
    with torch.no_grad():
        pred = model.predict_db(pairs, torch.as_tensor(FREQS[test])).numpy()
        model.use_network = False
        base = model.predict_db(pairs, torch.as_tensor(FREQS[test])).numpy()
    mae_net, mae_base = np.abs(pred - target[:, test]).mean(), np.abs(base - target[:, test]).mean()
    assert res.train_mae_db < res.base_train_mae_db
    assert mae_net < 0.5 * mae_base, (mae_net, mae_base)


def _measurements(path, fields):
    """A 'wideband' measurement file of the two squares (horns, 20 aspects at 3 m, 41 frequencies)."""
    geom = geometry(fields)
    centre = scene_centre(geom).numpy()
    freqs = FREQS[::5][:17]
    tx, rx, asp, rng = radar_links(np.arange(-20, 20, 2.0) * DEG, np.array([3.0]), centre)
    horn = AntennaPattern("horn")
    from rfir_stages.rf_fit.links import make_links

    cache = build_cache(geom, make_links(tx, rx, freqs, scene_centre(geom), "wideband"), horn, horn, None,
                        RenderSettings(visibility=False))
    g = geom.num
    m = Materials(torch.full((g,), 0.9, dtype=torch.float64), torch.full((g,), 3.0, dtype=torch.float64),
                  torch.full((g,), 0.5, dtype=torch.complex128))
    pg = 10 * np.log10(np.abs(render(cache, m).numpy()) ** 2)
    rcs = 10 * np.log10(rcs_from_path_gain(10 ** (pg / 10), rng[:, None], freqs[None], horn.boresight_gain,
                                           horn.boresight_gain))
    lo, hi = fields["gaussians/means"].min(0), fields["gaussians/means"].max(0)
    data = {"tx_pos": tx, "rx_pos": rx, "freq_hz": freqs, "path_gain_db": pg, "rcs_dbsm": rcs, "aspect_rad": asp,
            "range_m": rng, "split": (np.arange(len(asp)) % 2).astype(np.int64), "scene_bounds": np.stack([lo, hi])}
    write_artifact(path, "measurements", data, attrs={"task": "wideband", "scene": "two-squares"})
    return freqs


def test_rf_fit_and_predict_wideband_cli(tmp_path, monkeypatch):
    fields = _two_squares()
    write_scene_artifact(tmp_path / "scene.h5", fields)
    freqs = _measurements(tmp_path / "meas.h5", fields)
    monkeypatch.chdir(tmp_path)
    app = _app(["rf_fit.model=free", "rf_fit.occlusion=brute-force", "rf_fit.grid_step_deg=10.0",
                "predict.occlusion=brute-force", "rf_fit.wideband.base_iterations=20", "rf_fit.wideband.net_iterations=10",
                "rf_fit.wideband.hidden=16", "rf_fit.wideband.save_base=true"])
    run = CliRunner().invoke
    r = run(app, ["rf-fit", "scene.h5", "meas.h5", "-o", "rf.h5"])
    assert r.exit_code == 0, r.output
    rf = read_artifact(tmp_path / "rf.h5", "rf")
    attrs = rf.free["model@attrs"]
    assert int(attrs["wideband"]) == 1 and int(attrs["wideband.network"]) == 1
    assert attrs["wideband.f_min_hz"] == freqs.min() and attrs["wideband.f_max_hz"] == freqs.max()
    assert int(read_artifact(tmp_path / "rf_base.h5", "rf").free["model@attrs"]["wideband.network"]) == 0

    r = run(app, ["predict", "rcs", "rf.h5", "--measurements", "meas.h5", "-o", "pred.h5", "--plots", "plots",
                  "--results", "results/wb.json"])
    assert r.exit_code == 0, r.output
    doc = json.loads((tmp_path / "results/wb.json").read_text())
    assert doc["num_test"] == 10 and math.isfinite(doc["metrics"]["mae_db"])
    assert (tmp_path / "plots/spectrum_vs_frequency.png").stat().st_size > 1000
    # any frequency inside the band (not a fitted column), none outside
    inside = 0.5 * (freqs[3] + freqs[4])
    r = run(app, ["predict", "rcs", "rf.h5", "--aspects", "0,10", "--ranges", "3", "--freqs", f"{inside}", "-o", "p2.h5"])
    assert r.exit_code == 0, r.output
    assert np.isfinite(read_artifact(tmp_path / "p2.h5", "predictions")["rcs_dbsm"]).all()
    r = run(app, ["predict", "rcs", "rf.h5", "--aspects", "0", "--ranges", "3", "--freqs", "6.5e9", "-o", "p3.h5"])
    assert r.exit_code == 5 and "outside the fitted wideband range" in r.output
    assert "Traceback" not in r.output and not (tmp_path / "p3.h5").exists()


@pytest.mark.parametrize("bad", [{"freqs_per_step": 0}, {"net_iterations": -1}])
def test_bad_wideband_config(bad):
    from rfir_cli.errors import ConfigError

    with pytest.raises(ConfigError, match="rf_fit.wideband"):
        WidebandConfig.from_table(bad)


def test_float32_prediction_matches_float64():
    geom, links_fn, pairs = _setup()
    model = WidebandModel(torch.arange(geom.num), FREQS[0], FREQS[-1], knots=3)
    with torch.no_grad():
        model.base.theta_phi.copy_(torch.linspace(-3, 3, geom.num, dtype=torch.float64))
        model.net.linears[-1].weight.normal_(std=0.1)
        for net in (True, False):
            model.use_network = net
            d64 = model.predict_db(pairs, torch.as_tensor(FREQS))
            d32 = model.predict_db(pairs.to(torch.float32), torch.as_tensor(FREQS))
            assert (d64 - d32).abs().max() < 0.01
