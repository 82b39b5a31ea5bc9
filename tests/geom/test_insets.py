"""Insets (rfir_stages.geom.insets): rectangles of another colour or depth found on synthetic textured walls, none
on a bare textured wall, insets of one appearance on two walls given one class."""
from __future__ import annotations

import numpy as np
import pytest

from rfir_stages.geom.insets import InsetSettings, find_insets
from rfir_stages.geom.room_shell import Surface

WALL = (6.0, 3.0)                      # length along u, height along v [m]
DENSITY = 250.0                        # Gaussians per m^2 (the classroom's photo Gaussians: 200-300 on a wall)
PLASTER = np.array([0.78, 0.80, 0.84])
WOOD = np.array([0.55, 0.36, 0.20])    # a door against plaster: the classroom's colours
TEXTURE_STD = 0.08                     # per channel, over cells of 0.25 m: the classroom walls' measured spread ...
TEXTURE_CORR_M = 0.2                   # ... a cloud texture of this correlation length
GAUSSIAN_COLOUR_STD = 0.1              # each Gaussian's own colour noise, per channel
OFFSET_NOISE_M = 0.025                 # photo Gaussians scatter 2-3 cm along the normal ...
TILT_NOISE_DEG = 4.0                   # ... their normals some degrees
TOLERANCE_M = 0.1


def _texture(rng, size, std, corr_m, step=0.025):
    """A smooth random field on a grid of `step` over size (u, v) [m]: white noise filtered by a Gaussian of corr_m,
    scaled to std per channel; returns a function of (a, b) [M] m -> [M, 3]."""
    from scipy import ndimage

    shape = (int(size[0] / step) + 2, int(size[1] / step) + 2)
    field = np.stack([ndimage.gaussian_filter(rng.normal(size=shape), corr_m / step, mode="wrap") for _ in range(3)], -1)
    field *= std / field.reshape(-1, 3).std(0)
    return lambda a, b: field[np.clip((a / step).astype(int), 0, shape[0] - 1), np.clip((b / step).astype(int), 0, shape[1] - 1)]


def textured_wall(rng, insets=(), size=WALL, base=PLASTER, origin=(0.0, 0.0, 0.0), u=(1.0, 0.0, 0.0),
                  normal=(0.0, 1.0, 0.0), v=(0.0, 0.0, 1.0), name="wall_00"):
    """Gaussians of a wall (corner origin, along u and v, up by default, facing normal) with a cloud texture, colour and
    offset noise, and insets: (u0, u1, v0, v1) m, colour [3] or None (the wall's), offset [m] along the normal
    (negative: recessed), each with a texture of its own. Returns (x [N, 3], normals [N, 3], colors [N, 3], wall
    Surface)."""
    origin, u, v, normal = (np.asarray(w, float) for w in (origin, u, v, normal))
    n = int(DENSITY * size[0] * size[1])
    a, b = rng.random(n) * size[0], rng.random(n) * size[1]
    colors = base + _texture(rng, size, TEXTURE_STD, TEXTURE_CORR_M)(a, b)
    offset = np.zeros(n)
    for (u0, u1, v0, v1), colour, depth in insets:
        inside = (a >= u0) & (a < u1) & (b >= v0) & (b < v1)
        own = (base if colour is None else np.asarray(colour)) + _texture(rng, size, TEXTURE_STD, TEXTURE_CORR_M)(a, b)
        colors[inside] = own[inside]
        offset[inside] = depth
    colors = (colors + rng.normal(0, GAUSSIAN_COLOUR_STD, (n, 3))).clip(0, 1)
    x = origin + np.outer(a, u) + np.outer(b, v) + np.outer(offset + rng.normal(0, OFFSET_NOISE_M, n), normal)
    normals = normal + rng.normal(0, np.radians(TILT_NOISE_DEG) / np.sqrt(2), (n, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    cell = 0.1
    wall = Surface(name, name.split("_")[0], normal, float(origin @ normal), np.arange(n), 0.0, origin=origin, u=u, v=v,
                   occupied=np.ones((int(round(size[0] / cell)), int(round(size[1] / cell))), bool), cell_m=cell)
    return x, normals, colors, wall


def _rect_of(inset):
    i, j = np.nonzero(inset.occupied)
    c = inset.cell_m
    return i.min() * c, (i.max() + 1) * c, j.min() * c, (j.max() + 1) * c


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_bare_textured_wall_has_no_inset(seed):
    x, normals, colors, wall = textured_wall(np.random.default_rng(seed))
    assert find_insets(x, normals, colors, [wall], InsetSettings()) == []
    assert wall.occupied.all()


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("kind", ["door", "recessed"])
def test_rectangle_found_within_10_cm(seed, kind):
    rect, colour, depth = {"door": ((1.1, 2.05, 0.0, 2.1), WOOD, 0.0),               # another colour, at the floor
                           "recessed": ((1.5, 3.0, 0.9, 2.3), None, -0.06)}[kind]   # the wall's colour, set 6 cm in
    x, normals, colors, wall = textured_wall(np.random.default_rng(seed), insets=[(rect, colour, depth)])
    insets = find_insets(x, normals, colors, [wall], InsetSettings())
    assert len(insets) == 1, [s.name for s in insets]
    found = _rect_of(insets[0])
    assert np.abs(np.subtract(found, rect)).max() <= TOLERANCE_M, (found, rect)
    assert insets[0].name == "inset_a_00" and insets[0].kind == "inset"
    assert not (insets[0].occupied & wall.occupied).any() and (wall.inset_cells == insets[0].occupied).all()


def test_one_appearance_on_two_walls_is_one_class():
    rng = np.random.default_rng(7)
    door = ((1.0, 2.0, 0.0, 2.1), WOOD, 0.0)
    x1, n1, c1, w1 = textured_wall(rng, insets=[door, ((3.5, 5.0, 1.0, 2.2), None, -0.06)])
    x2, n2, c2, w2 = textured_wall(rng, insets=[door], base=np.array([0.60, 0.65, 0.75]), origin=(0.0, 4.0, 0.0),
                               normal=(0.0, -1.0, 0.0))
    w2.name = "wall_01"
    x, normals, colors = np.concatenate([x1, x2]), np.concatenate([n1, n2]), np.concatenate([c1, c2])
    w2.members = w2.members + len(x1)
    insets = find_insets(x, normals, colors, [w1, w2], InsetSettings())
    names = sorted(s.name for s in insets)
    classes = {n.rsplit("_", 1)[0] for n in names}
    assert len(insets) == 3 and len(classes) == 2, names
    # the two doors share the class, the recessed window has its own
    door_names = [s.name for s in insets if abs(_rect_of(s)[0] - 1.0) <= TOLERANCE_M]
    assert len(door_names) == 2 and door_names[0].rsplit("_", 1)[0] == door_names[1].rsplit("_", 1)[0]


def test_floor_rug_is_an_inset():
    rug = (1.2, 3.4, 0.8, 2.3)
    x, normals, colors, floor = textured_wall(np.random.default_rng(11), insets=[(rug, np.array([0.25, 0.3, 0.55]), 0.0)],
                                              size=(5.0, 4.0), base=np.array([0.55, 0.52, 0.48]), u=(1.0, 0.0, 0.0),
                                              v=(0.0, 1.0, 0.0), normal=(0.0, 0.0, 1.0), name="floor")
    insets = find_insets(x, normals, colors, [floor], InsetSettings())
    assert len(insets) == 1 and np.abs(np.subtract(_rect_of(insets[0]), rug)).max() <= TOLERANCE_M


def test_bright_panes_over_a_quarter_of_a_wall_are_found():
    """Three windows (daylight through them: bright) cover a quarter of the wall: the median and spread of all cells
    would lean towards them and hide them; the wall's own cells (the larger mode of a bimodal brightness) do not.
    Over ten walls, all three panes on at least nine, each within 10 cm."""
    # 0.25 brighter than the wall, three texture spreads: found by the wall's own spread, hidden by the spread of all
    panes = [((u0, u0 + 1.5, 0.9, 2.3), np.array([0.75, 0.75, 0.75]), 0.0) for u0 in (1.5, 4.0, 6.5)]
    complete = 0
    for seed in range(10):
        x, normals, colors, wall = textured_wall(np.random.default_rng(seed), insets=panes, size=(9.0, 2.9),
                                                 base=np.array([0.50, 0.53, 0.50]))
        insets = find_insets(x, normals, colors, [wall], InsetSettings())
        assert {s.name.rsplit("_", 1)[0] for s in insets} <= {"inset_a"}, [s.name for s in insets]
        for found in (_rect_of(s) for s in insets):
            assert min(np.abs(np.subtract(found, rect)).max() for rect, _, _ in panes) <= TOLERANCE_M, found
        complete += len(insets) == 3
    assert complete >= 9, complete
