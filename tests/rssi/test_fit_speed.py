"""Device gains profiled out of the room fit (fit_physical's profile_gains, device_gains.DeviceGains.profile) and the
fit on whole devices (device_gains.whole_device_rows) with every gain then taken from all links
(fit_physical.gains_from_all_links): a walk survey of the reduced test room whose levels carry a known offset per
receiver position."""
import numpy as np
import pytest
import torch
from typer.testing import CliRunner

from rfir_cli.main import app
from rfir_core.artifacts import read_artifact, write_artifact
from rfir_stages.model.device_gains import DeviceGains, device_index, gains_at, whole_device_rows
from rfir_stages.model.fit_physical import PhysicalFitConfig, fit_materials, gains_from_all_links, predict_db
from rfir_stages.model.physical import MaterialParams

from .helpers import reference_gain_db, room_geometry, write_scene

TX = np.array([[0.7, 0.6, 2.0], [3.3, 0.6, 2.0], [0.7, 2.4, 2.0], [3.3, 2.4, 2.0]])
NUM_POSITIONS = 60
OFFSET_STD_DB = 3.0
NOISE_DB = 0.5


def _walk(seed: int = 0):
    """(tx [M, 3], rx [M, 3], position of each link [M], offset [P] dB): the 4 transmitters TX to one receiver
    carried to NUM_POSITIONS positions at 1 m, and a gain offset per position."""
    rng = np.random.default_rng(seed)
    rx = np.column_stack([rng.uniform(0.3, 3.7, NUM_POSITIONS), rng.uniform(0.3, 2.7, NUM_POSITIONS),
                          np.full(NUM_POSITIONS, 1.0)])
    ti, ri = np.repeat(np.arange(len(TX)), NUM_POSITIONS), np.tile(np.arange(NUM_POSITIONS), len(TX))
    return TX[ti], rx[ri], ri, rng.normal(0.0, OFFSET_STD_DB, NUM_POSITIONS)


@pytest.fixture(scope="module")
def survey():
    """The walk traced in the reduced room; levels are the room model's at known materials plus the offsets and
    N(0, NOISE_DB) (the test is of the gains, not of the physics): (room, links, tx, rx, position [M], offset [P],
    physical [M] dB, target [M] dB)."""
    room, _, _ = room_geometry(0.3)
    tx, rx, pos, offset = _walk()
    links = room.links(tx, rx, np.full(len(tx), 2.4e9))
    true = MaterialParams(room.num_materials, eps_r=5.0, sigma_1ghz=0.05, scattering=0.3, thickness_m=0.1,
                          shared_scattering=True)
    with torch.no_grad():
        physical = predict_db(links, true)[:, 0].numpy()
    noise = np.random.default_rng(1).normal(0.0, NOISE_DB, len(tx))
    return room, links, tx, rx, pos, offset, physical, physical + offset[pos] + noise


def _cfg(profile: bool) -> PhysicalFitConfig:
    return PhysicalFitConfig(iterations=60, start_iterations=15, fit_gain=True, shared_scattering=True,
                             profile_gains=profile)


def _centred(x: np.ndarray) -> np.ndarray:
    return x - x.mean()


def _link_gains(devices: DeviceGains, rows=None) -> np.ndarray:
    """The gain [M] dB of each link the devices were built from (rows: of these links)."""
    index = devices.all_index["rx"].numpy()
    g = devices.gains["rx"].detach().numpy()[index]
    return g if rows is None else g[rows]


def test_profiled_gains_fit_as_the_joint_fit_does_and_recover_the_offsets(survey):
    room, links, tx, rx, pos, offset, physical, target = survey
    fits = {}
    for profile in (True, False):
        devices = DeviceGains("rx", tx, rx, 3.0)
        res = fit_materials(links, room.num_materials, target[:, None], _cfg(profile), devices=devices)
        with torch.no_grad():
            pred = predict_db(links, res.params)[:, 0].numpy() + float(res.params.gain_db)
        fits[profile] = (res, pred, _link_gains(devices))
    (prof, p_pred, p_gain), (joint, j_pred, j_gain) = fits[True], fits[False]
    # the same fit: the physical prediction (materials and system gain) and the gains agree well inside the noise
    # (NOISE_DB; either fit is a few tenths of a dB from the truth after 60 steps); the level common to
    # all gains trades with the system gain, so each is compared about its mean
    assert np.abs(_centred(p_pred) - _centred(j_pred)).mean() < 0.25, np.abs(_centred(p_pred) - _centred(j_pred)).mean()
    assert np.abs(_centred(p_gain) - _centred(j_gain)).mean() < 0.25, np.abs(_centred(p_gain) - _centred(j_gain)).mean()
    assert prof.train_mae_db < joint.train_mae_db + 0.02
    # and the gains are the offsets put into the data: within the noise over 4 links a position (0.25 dB) and the
    # prior's shrinkage
    err = _centred(p_gain) - _centred(offset[pos])
    assert np.abs(err).mean() < 0.35 and np.abs(err).max() < 1.2, (np.abs(err).mean(), np.abs(err).max())
    # the materials too: the physical levels within the noise
    assert np.abs(_centred(p_pred) - _centred(physical)).mean() < 0.5


def test_profiled_gains_are_the_closed_form_optimum_for_the_fitted_materials(survey):
    """After a profiled fit the gains solve the ridge problem of the final materials exactly: per position the
    residuals' sum over (links + s^2 / prior^2), s^2 the mean squared residual after the gains."""
    room, links, tx, rx, pos, offset, physical, target = survey
    devices = DeviceGains("rx", tx, rx, 3.0)
    res = fit_materials(links, room.num_materials, target[:, None], _cfg(True), devices=devices)
    with torch.no_grad():
        fitted = predict_db(links, res.params, 10 ** ((target.min() - 30) / 10))[:, 0].numpy()
    r = target - fitted
    g = devices.gains["rx"].detach().numpy()
    d = devices.index["rx"].numpy()
    lam = np.mean((r - g[d]) ** 2) / 3.0 ** 2
    want = np.bincount(d, r) / (np.bincount(d) + lam)
    np.testing.assert_allclose(g, want, atol=1e-4)


def test_both_sides_profiled_side_by_side_reach_the_joint_ridge_optimum():
    """Two sides (a gain per transmitter and per position): the side-by-side sweeps end at the joint ridge optimum,
    checked against its normal equations solved directly (with the s^2 the solve took: the mean squared residual
    after the gains it started from)."""
    tx, rx, pos, offset = _walk(seed=4)
    ti = np.repeat(np.arange(len(TX)), NUM_POSITIONS)
    r = offset[pos] + np.array([1.0, -2.0, 0.5, 0.0])[ti] + np.random.default_rng(5).normal(0, 0.5, len(pos))
    devices = DeviceGains("both", tx, rx, 2.0)
    i_tx, i_rx = (devices.index[s].numpy() for s in ("tx", "rx"))
    devices.profile(torch.as_tensor(r))
    start = {s: devices.gains[s].detach().numpy().copy() for s in ("tx", "rx")}
    devices.profile(torch.as_tensor(r))
    lam = np.mean((r - start["tx"][i_tx] - start["rx"][i_rx]) ** 2) / 2.0 ** 2
    # mean (r - A g)^2 + lam / M |g|^2, A [M, T + P] the incidence of both sides
    a = np.zeros((len(r), len(TX) + NUM_POSITIONS))
    a[np.arange(len(r)), i_tx] = 1.0
    a[np.arange(len(r)), len(TX) + i_rx] = 1.0
    want = np.linalg.solve(a.T @ a + lam * np.eye(a.shape[1]), a.T @ r)
    got = np.concatenate([devices.gains["tx"].detach().numpy(), devices.gains["rx"].detach().numpy()])
    np.testing.assert_allclose(got, want, atol=1e-4)


def test_whole_devices_keep_every_link_of_the_devices_taken():
    tx, rx, pos, _ = _walk()
    rows = whole_device_rows("rx", 100, tx, rx, {"tx": None, "rx": None})
    _, device, _ = device_index(rx, None)
    taken = np.unique(device[rows])
    assert abs(len(rows) - 100) <= len(TX)                               # whole devices of 4 links each
    assert np.isin(np.flatnonzero(np.isin(device, taken)), rows).all()   # every link of a device taken
    assert len(np.unique(device[rows])) == len(rows) // len(TX)
    # the other side keeps its share: each transmitter a quarter of the rows
    assert np.bincount(device_index(tx, None)[1][rows]).tolist() == [len(rows) // 4] * 4
    # "both": the side with the most devices is taken whole; all rows when the count covers them
    assert np.array_equal(whole_device_rows("both", 100, tx, rx, {"tx": None, "rx": None}), rows)
    assert len(whole_device_rows("rx", 10_000, tx, rx, {"tx": None, "rx": None})) == len(tx)


def test_a_fit_on_whole_devices_gives_every_device_its_gain_from_all_links(survey):
    """Materials fitted on half the positions (whole devices); gains_from_all_links then gives the positions the fit
    never saw their offsets too, tracing their links in chunks."""
    room, links, tx, rx, pos, offset, physical, target = survey
    fit = whole_device_rows("rx", len(tx) // 2, tx, rx, {"tx": None, "rx": None})
    devices = DeviceGains("rx", tx, rx, 3.0, rows=fit)
    assert devices.num_devices == NUM_POSITIONS and devices.num_fitted == len(fit) // len(TX)
    res = fit_materials(links.select_links(torch.as_tensor(fit)), room.num_materials, target[fit, None], _cfg(True),
                        devices=devices)
    unseen = ~np.isin(np.arange(len(tx)), fit)
    assert np.all(_link_gains(devices)[unseen] == 0.0)           # the fit leaves the devices it did not see at 0
    traced = []

    def links_of(rows):
        traced.append(len(rows))
        return room.links(tx[rows], rx[rows], np.full(len(rows), 2.4e9))
    physical = gains_from_all_links(devices, res.params, links.select_links(torch.as_tensor(fit)), fit, links_of,
                                    target, chunk_links=50)
    assert traced == [50, 50, 20]                                 # the 120 links the fit did not use, in chunks
    with torch.no_grad():                                         # every link's prediction, in the training order
        whole = predict_db(links, res.params, 10 ** ((target[fit].min() - 30) / 10))[:, 0].numpy()
    np.testing.assert_allclose(physical, whole, atol=1e-9)
    err = _centred(_link_gains(devices)) - _centred(offset[pos])
    assert np.abs(err[unseen]).mean() < 0.4 and np.abs(err).max() < 1.5, (np.abs(err).mean(), np.abs(err).max())


@pytest.fixture(scope="module")
def walk_file(tmp_path_factory):
    """The walk survey as a measurements file of the reduced room (no simulator: measured data), levels from the
    independent closed form (helpers.reference_gain_db) plus the offsets per position and N(0, NOISE_DB); the
    test rows are every fifth link."""
    d = tmp_path_factory.mktemp("walk_fit")
    write_scene(d / "scene.h5", spacing_m=0.3)
    tx, rx, pos, offset = _walk()
    level = reference_gain_db(tx, rx, 2.4e9) + offset[pos] + np.random.default_rng(2).normal(0, NOISE_DB, len(tx))
    split = (np.arange(len(tx)) % 5 == 0).astype(np.int64)
    write_artifact(d / "meas.h5", "measurements", {"tx_pos": tx, "rx_pos": rx, "freq_hz": np.array([2.4e9]),
                                                   "path_gain_db": level[:, None], "split": split},
                   attrs={"task": "rssi", "scene": "walk"})
    return d, tx, rx, pos, offset, split


def test_rf_fit_takes_whole_devices_and_says_so(walk_file):
    """rf-fit with a gain per position and fit_links under the training links: the materials on whole positions,
    the printed words say on which links, and the model stores a gain for every training position, the offsets."""
    d, tx, rx, pos, offset, split = walk_file
    r = CliRunner().invoke(app, ["--set", "rf_fit.physical.iterations=40", "--set", "rf_fit.physical.start_iterations=10",
                                 "--set", "rf_fit.room.device_gains=rx", "--set", "rf_fit.room.fit_links=96",
                                 "--set", "rf_fit.room.reflection_ranges=false", "--set", "rf_fit.room.band=coherent",
                                 "rf-fit", str(d / "scene.h5"), str(d / "meas.h5"), "-o", str(d / "rf.h5")])
    assert r.exit_code == 0, r.output
    train = split == 0
    assert "the materials fitted on 96 of the 192 training links, whole devices (4 tx and 24 rx devices" in r.output
    assert "device gains: each from all its links (192 training links, 96 of them traced for it)" in r.output
    model = read_artifact(d / "rf.h5", "rf").free["model"]
    assert len(model["device_rx_gain_db"]) == len(np.unique(pos[train]))
    got, matched = gains_at(model, np.full_like(tx[train], 99.0), rx[train])
    assert matched == train.sum()
    err = _centred(got) - _centred(offset[pos[train]])
    # the room model against the closed form's levels adds its own error per position (test_device_gains: < 1 dB)
    assert np.abs(err).mean() < 0.8, np.abs(err).mean()


def test_the_diffuse_matrix_form_equals_the_diffuse_terms_with_gradients(survey):
    """RoomLinks evaluates its diffuse power as matrix products (room.DiffuseMatrix) from its second evaluation on:
    the power and its gradient with respect to every material property equal DiffuseTerms.power's to rounding."""
    room, links, tx, rx, *_ = survey
    assert len(links.diffuse.obstructed.link) > 0           # terms through surfaces, the sparse part, are exercised
    params = MaterialParams(room.num_materials, eps_r=4.0, sigma_1ghz=0.02, scattering=0.4, thickness_m=0.08)
    raw = (params.t_eps, params.t_sig, params.t_s, params.t_th)
    out = []
    fresh = links.select_links(torch.arange(links.num_links))      # no matrix built yet
    for _ in range(2):
        diff = fresh.components(params.values())[1]
        grads = torch.autograd.grad(torch.log(diff).sum(), raw)
        out.append((diff.detach(), grads))
    assert fresh._diffuse_matrix is not None
    (d0, g0), (d1, g1) = out
    np.testing.assert_allclose(d1.numpy(), d0.numpy(), rtol=1e-12)
    for a, b in zip(g0, g1):
        np.testing.assert_allclose(b.numpy(), a.numpy(), rtol=1e-9, atol=1e-12 * float(a.abs().max()))
