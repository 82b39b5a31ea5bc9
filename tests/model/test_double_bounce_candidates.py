"""The double bounces' candidate search (second_order.crossing_candidates, one [M', B] product per side
of the plane) against the straightforward grid test it replaces and against the crossing computed
point by point."""
import numpy as np
import pytest

from rfir_stages.model.second_order import _crossing_near, crossing_candidates


def _case(seed: int, num_tx: int = 300, num_b: int = 400):
    """Antennas 2-5 m around a plane through the origin, surfels within 0.3 m of it (both sides)."""
    rng = np.random.default_rng(seed)
    na = rng.normal(size=3)
    na /= np.linalg.norm(na)
    d = rng.normal(size=(num_tx, 3))
    tx = d / np.linalg.norm(d, axis=1, keepdims=True) * rng.uniform(2.0, 5.0, (num_tx, 1))
    xb = rng.uniform(-0.3, 0.3, (num_b, 3))
    return tx, tx @ na, xb, xb @ na, na


def _grid(tx, side_tx, xb, side_b, na, reach):
    same_side = np.sign(side_tx)[:, None] == np.sign(side_b)[None]
    return np.nonzero(same_side & _crossing_near(tx, side_tx, xb, side_b, na, reach))


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("block", [1 << 22, 1000])   # one product per side, or many row blocks
def test_candidates_equal_the_grid_test(seed, block):
    tx, side_tx, xb, side_b, na = _case(seed)
    li, bi = crossing_candidates(tx, side_tx, xb, side_b, na, 0.12, block=block)
    ref_i, ref_b = _grid(tx, side_tx, xb, side_b, na, 0.12)
    assert 0 < li.size < tx.shape[0] * xb.shape[0] // 2      # the test selects: neither none nor all
    np.testing.assert_array_equal(li, ref_i)                  # the same pairs in the same (row-major) order
    np.testing.assert_array_equal(bi, ref_b)


def test_every_pair_whose_segment_crosses_within_reach_is_a_candidate():
    """Exact crossings (Tx's image in the plane -> m, intersected with the plane), computed pair by
    pair: all within the reach are candidates, none beyond 1.01 x the reach."""
    tx, side_tx, xb, side_b, na = _case(3, 120, 150)
    reach = 0.1
    li, bi = crossing_candidates(tx, side_tx, xb, side_b, na, reach)
    got = set(zip(li.tolist(), bi.tolist()))
    inside = outside = 0
    for i in range(len(tx)):
        img = tx[i] - 2.0 * side_tx[i] * na
        for j in range(len(xb)):
            if np.sign(side_tx[i]) != np.sign(side_b[j]):
                assert (i, j) not in got
                continue
            t = -(img @ na) / ((xb[j] - img) @ na)
            dist = np.linalg.norm(img + t * (xb[j] - img))
            if dist <= reach:
                inside += 1
                assert (i, j) in got
            elif dist > 1.01 * reach:
                outside += 1
                assert (i, j) not in got
    assert inside > 0 and outside > 0
