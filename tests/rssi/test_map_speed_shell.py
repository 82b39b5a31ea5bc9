"""Radio maps for new receivers: the shell split of the tracer and the lazily traced visibility rows.

On the reduced room (walls, floor, ceiling, a partition with a doorway, a table):
- ShellSplitOcclusion gives TracerOcclusion's transmittances (to 1e-12 relative where either is above
  t_stop, both below t_stop otherwise), for segments from inside the room, from points a few mm from the
  floor and walls and from outside, to every surfel;
- the segments it lets skip the shell meet no shell Gaussian in the brute-force oracle (every segment
  against every Gaussian, float64 torch): the geometric claim the split rests on;
- CellVisibility traces only the entries a call needs and completes the rows later: the same rows as one
  full trace, with fewer segments traced.
"""
import numpy as np
import pytest
import torch

from rfir_stages.model.room_diffuse import CellVisibility
from rfir_stages.rf_fit.occlusion import BruteForceOcclusion, ShellSplitOcclusion, TracerOcclusion, segment_rays

from .helpers import ROOM, room_geometry

T_STOP = 1e-4


@pytest.fixture(scope="module")
def room():
    return room_geometry(0.3, occlusion="tracer")


def _points(rng, n):
    """Points inside the room, a few near the floor, a wall and the ceiling, two outside."""
    lx, ly, lz = ROOM
    p = rng.uniform([0.1, 0.1, 0.1], [lx - 0.1, ly - 0.1, lz - 0.1], (n, 3))
    p[:4, 2] = 0.004                        # 4 mm above the floor
    p[4:8, 0] = lx - 0.003                  # 3 mm from a wall
    p[8:10, 2] = lz - 0.002
    p[10] = [lx + 0.5, 1.0, 1.0]            # outside
    p[11] = [1.0, 1.0, -0.3]
    return p


def _segments(room, n_points, seed=0):
    g = room.provider.geom
    rng = np.random.default_rng(seed)
    pts = _points(rng, n_points)
    o = torch.as_tensor(np.repeat(pts, g.num, 0))
    ids = torch.arange(g.num).repeat(n_points)
    return o, ids


def test_the_shell_split_gives_the_single_bvhs_transmittances(room):
    room, labels, names = room
    provider = room.provider
    assert isinstance(provider, TracerOcclusion)
    split = ShellSplitOcclusion(provider)
    shell = np.zeros(provider.geom.num, bool)
    shell[split.parts[1][0].numpy()] = True
    bounding = np.isin(labels, [names.index(n) for n in ("floor", "ceiling", "wall_a", "wall_b", "wall_c", "wall_d")])
    assert shell[bounding].mean() > 0.9 and not shell[labels == names.index("table_00")].all()
    o, ids = _segments(room, 24)
    op = torch.full((provider.geom.num,), 0.9, dtype=torch.float64)
    # 0.1 m: the diffuse cells' margin; 2.5 mm: few segments to the shell's own surfels end clear of its slabs
    for margin, least_clear in ((0.1, 0.3), (0.0025, 0.03)):
        want = provider.segment_transmittance(o, ids, margin, op, T_STOP).numpy()
        got = split.segment_transmittance(o, ids, margin, op, T_STOP).numpy()
        clear = split.clear_of_shell(*segment_rays(o, provider.geom.means[ids], margin)).numpy()
        assert least_clear < clear.mean() < 0.97            # both ways taken
        assert (want[~clear] < 0.99).mean() > 0.1           # segments that need the shell meet it
        above = (want >= T_STOP) | (got >= T_STOP)
        np.testing.assert_allclose(got[above], want[above], rtol=1e-12, atol=0)
        assert (got[~above] < T_STOP).all() and (want[~above] < T_STOP).all()


def test_segments_clear_of_the_shell_meet_no_shell_gaussian_in_the_brute_force(room):
    room, _, _ = room
    provider = room.provider
    split = ShellSplitOcclusion(provider)
    shell = set(split.parts[1][0].tolist())
    g = provider.geom
    o, ids = _segments(room, 14, seed=1)
    keep = torch.arange(len(ids)) % 7 == 0                 # a subset: the oracle is every pair
    o, ids = o[keep], ids[keep]
    margin = 0.1
    oo, d, t_max = segment_rays(o, g.means[ids], margin)
    clear = split.clear_of_shell(oo, d, t_max)
    oracle = BruteForceOcclusion(g, provider.alpha_min)
    hits = oracle.segment_hits(o[clear], ids[clear])
    length = (g.means[ids[clear]][hits.query] - o[clear][hits.query]).norm(dim=-1)
    on = hits.t_m < length - margin                          # the part the trace covers
    assert int(clear.sum()) > 1000 and int(on.sum()) > 100  # the oracle sees hits on them, none in the shell
    assert not shell & set(hits.gaussian[on].tolist())
    nearby = oracle.segment_hits(o[~clear], ids[~clear])    # the segments not clear do meet the shell
    assert shell & set(nearby.gaussian.tolist())


class _Counting:
    """A provider that counts the segments it traces."""

    def __init__(self, provider):
        self.provider, self.geom, self.traced = provider, provider.geom, 0

    def segment_transmittance(self, origins, target_ids, margin_m, opacity, t_stop=1e-4):
        self.traced += len(target_ids)
        return self.provider.segment_transmittance(origins, target_ids, margin_m, opacity, t_stop)


def test_rows_traced_where_needed_then_completed_equal_full_rows(room):
    room, _, _ = room
    s = room.settings
    rng = np.random.default_rng(3)
    lx, ly, lz = ROOM
    pts = rng.uniform([0.2, 0.2, 0.5], [lx - 0.2, ly - 0.2, 1.5], (9, 3))
    pts = np.concatenate([pts, pts[:2]])                    # repeated points share a row
    c = len(room.cells.area)
    need = rng.random((len(pts), c)) < 0.4
    counting = _Counting(room.provider)
    lazy = CellVisibility(room.cells, counting, s.opacity, s.diffuse_margin_m, s.t_stop)
    v1, i1 = lazy(pts, need)
    union = np.zeros((9, c), bool)
    np.logical_or.at(union, i1, need)
    assert counting.traced == union.sum() < 9 * c
    full = CellVisibility(room.cells, room.provider, s.opacity, s.diffuse_margin_m, s.t_stop)
    want, iw = full(pts)
    np.testing.assert_array_equal(i1, iw)
    np.testing.assert_array_equal(v1[union], want[union])
    assert (v1[~union] == 0).all()
    v2, _ = lazy(pts)                                        # completed: only the rest traced
    assert counting.traced == 9 * c and len(lazy) == 9
    np.testing.assert_array_equal(v2, want)
