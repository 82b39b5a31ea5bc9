"""rf-fit's link subsample with device gains on (rf_fit.room_stage.devices_kept): a gain per fixed anchor keeps its
links in the evenly spaced subsample of rf_fit.room.fit_links, a gain per surveyed position does not (every training
link is then fitted)."""
import numpy as np

from rfir_stages.rf_fit.room_stage import MIN_DEVICE_LINKS, devices_kept


def _survey(positions: int, anchors: int):
    """Links of `positions` surveyed points (tx, ids 0..) to `anchors` fixed receivers (rx, ids 100..), [M, 3] m."""
    rng = np.random.default_rng(0)
    pts, anc = rng.uniform(0, 8, (positions, 3)), rng.uniform(0, 8, (anchors, 3))
    t, r = np.repeat(pts, anchors, 0), np.tile(anc, (positions, 1))
    ids = {"tx": np.repeat(np.arange(positions), anchors), "rx": np.tile(100 + np.arange(anchors), positions)}
    return t, r, ids


def test_anchor_gains_keep_the_subsample_position_gains_do_not():
    t, r, ids = _survey(900, 6)                                   # 5400 links, 900 links an anchor
    sub = np.linspace(0, len(t) - 1, 1500).round().astype(np.int64)
    assert devices_kept("rx", sub, t, r, ids)                     # 250 links an anchor in the subsample
    assert not devices_kept("tx", sub, t, r, ids)                 # 6 links a position at most
    assert not devices_kept("both", sub, t, r, ids)
    # the bound itself: an anchor left with MIN_DEVICE_LINKS - 1 links fails, with MIN_DEVICE_LINKS passes
    few = np.flatnonzero(ids["rx"] == 100)
    rest = np.flatnonzero(ids["rx"] != 100)[:1000]
    assert devices_kept("rx", np.concatenate([rest, few[:MIN_DEVICE_LINKS]]), t, r, ids)
    assert not devices_kept("rx", np.concatenate([rest, few[:MIN_DEVICE_LINKS - 1]]), t, r, ids)
    # devices told apart by position where the file has no ids
    assert devices_kept("rx", sub, t, r, {"tx": None, "rx": None})
