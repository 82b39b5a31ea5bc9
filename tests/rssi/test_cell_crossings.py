"""The surfaces crossed on the legs to the diffuse cells (room_diffuse.CellCrossings), on the reduced room.

- rows traced only where a call needs them and completed later equal one full trace, with fewer legs
  traced, and repeated points share a row;
- a leg from one side of the partition to a cell on the other side crosses the partition (outside the
  doorway) and nothing else; legs within one half of the empty part of the room cross nothing.
"""
import numpy as np
import pytest

from rfir_stages.model.room_diffuse import BLOCKED, NO_CROSSING, UNTRACED, CellCrossings

from .helpers import DOOR, PART_X, ROOM, room_geometry


@pytest.fixture(scope="module")
def room():
    return room_geometry(0.3, occlusion="tracer")


class _Counting:
    """A provider that counts the rays it traces."""

    def __init__(self, provider):
        self.provider, self.geom, self.traced = provider, provider.geom, 0

    def ray_hits(self, origins, directions, *args, **kw):
        self.traced += len(origins)
        return self.provider.ray_hits(origins, directions, *args, **kw)


def test_rows_traced_where_needed_then_completed_equal_full_rows(room):
    room, _, _ = room
    rng = np.random.default_rng(3)
    lx, ly, lz = ROOM
    pts = rng.uniform([0.2, 0.2, 0.5], [lx - 0.2, ly - 0.2, 1.5], (9, 3))
    pts = np.concatenate([pts, pts[:2]])                    # repeated points share a row
    c = len(room.cells.area)
    need = rng.random((len(pts), c)) < 0.4
    counting = _Counting(room.provider)
    lazy = CellCrossings(room.cells, room.patches, counting)
    x1, i1 = lazy(pts, need)
    union = np.zeros((9, c), bool)
    np.logical_or.at(union, i1, need)
    assert counting.traced == union.sum() < 9 * c
    full = CellCrossings(room.cells, room.patches, room.provider)
    want, iw = full(pts)
    np.testing.assert_array_equal(i1, iw)
    np.testing.assert_array_equal(x1[union], want[union])
    assert (x1[~union][:, 0] == UNTRACED).all()
    assert (want[:, :, 0] != UNTRACED).all()
    x2, _ = lazy(pts)                                        # completed: only the rest traced
    assert counting.traced == 9 * c and len(lazy) == 9
    np.testing.assert_array_equal(x2, want)


def test_legs_across_the_partition_cross_it_and_nothing_else(room):
    room, labels, names = room
    part = names.index("partition")
    patch_label = room.patches.label
    cells = room.cells
    a = np.array([[0.7, 2.2, 1.6]])                      # the partition's x < PART_X side, above the table
    rows, _ = room.cell_crossings(a)
    row = rows[0]
    assert (row[:, 0] != BLOCKED).all()
    crossed = row[:, 0] >= 0
    # cells on the far side whose leg meets the partition's plane well inside the wall and outside the doorway
    b = cells.anchor_m
    f = (PART_X - a[0, 0]) / np.where(b[:, 0] != a[0, 0], b[:, 0] - a[0, 0], 1e-12)
    y, z = a[0, 1] + f * (b[:, 1] - a[0, 1]), a[0, 2] + f * (b[:, 2] - a[0, 2])
    in_door = (y > DOOR[0] - 0.1) & (y < DOOR[1] + 0.1) & (z < DOOR[3] + 0.1)
    far = (b[:, 0] > PART_X + 0.3) & (y > 0.1) & (y < ROOM[1] - 0.1) & (z > 0.1) & (z < ROOM[2] - 0.1) & ~in_door
    assert far.sum() >= 5
    assert crossed[far].all()
    assert (patch_label[row[far, 0]] == part).all() and (row[far, 1:] == NO_CROSSING).all()
    # cells on the near side, high on the walls and ceiling (nothing between), are reached directly
    near = (cells.anchor_m[:, 0] < PART_X - 0.3) & (cells.anchor_m[:, 2] > 1.9)
    assert near.sum() >= 3 and not crossed[near].any()
