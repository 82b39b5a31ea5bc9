"""Room link physics (rfir_stages.model.room_paths / room_diffuse) against closed forms.

- a perfect-conductor plane: direct + image path, the reflected field -(I - 2 n n^T) E (two-ray
  interference including its nulls), for V and H polarisation;
- a dielectric wall seen in a horizontal plane with V polarisation is pure TE: R_TE(theta) exactly;
- a wall between the antennas: the direct path is attenuated by the slab formula T(theta), once,
  whatever the number of Gaussians tiling the wall; a metal wall blocks it;
- a window opening: no reflection where the wall has no surfels;
- a metal corner: the second-order path of the image method, length and amplitude;
- a direct path through three partitions and a floor reflection through them: kept or dropped by the number of
  interactions (reflections plus surfaces crossed) a path may have;
- a metal corner cube: the third-order path of an independent image-method enumeration, its ordering, length
  and amplitude (the free-space field at the image distance).
"""
import math

import numpy as np
import pytest
import torch

from rfir_core.physics.materials import C0, fresnel, itu_law, permittivity, slab_transmission
from rfir_core.physics.polarisation import antenna_polarisation
from rfir_stages.model.room_paths import build_patch_set, trace_room_paths
from rfir_stages.model.surfels import surfel_areas
from rfir_stages.model.occlusion import make_provider

from .helpers import plate_mesh, surfels

F = 2.4e9
LAM = C0 / F
K = 2 * math.pi / LAM
METAL = complex(1.0, -math.inf)   # a perfect conductor (materials.fresnel)


def _surfels_of(meshes, spacing, rectangles=False):
    """(geometry, labels [G], areas [G]) of a list of (vertices, faces) meshes, one label each (rectangles: the
    mesh's rectangles tiled as cells, gaussians_from_mesh)."""
    vs, fs, ls, off = [], [], [], 0
    for i, (v, f) in enumerate(meshes):
        vs.append(v)
        fs.append(f + off)
        ls.append(np.full(len(f), i))
        off += len(v)
    geom, g = surfels(np.concatenate(vs), np.concatenate(fs), spacing, labels=np.concatenate(ls), rectangles=rectangles)
    labels = torch.as_tensor(g["gaussians/labels"], dtype=torch.int64)
    return geom, labels, surfel_areas(geom.means, geom.log_scales, geom.rotations, geom.normals)


def _room(meshes, spacing=0.25, extent="disks"):
    """Surfels, patches and a provider for a list of (vertices, faces) meshes, one label each."""
    geom, labels, areas = _surfels_of(meshes, spacing)
    return build_patch_set(geom, areas, labels, coplanar_m=0.01, extent=extent), make_provider("auto", geom)


def _field(paths, patches, eta_of_label, thickness_of_label=None, s=0.0):
    lab = torch.as_tensor(patches.label)
    eta = torch.as_tensor(np.asarray(eta_of_label, dtype=np.complex128))[lab][:, None]
    th = None if thickness_of_label is None else torch.as_tensor(np.asarray(thickness_of_label, float))[lab]
    return paths.field(eta, th, torch.full((patches.num,), float(s), dtype=torch.float64)).numpy()


def _free(d):
    return LAM / (4 * math.pi * d) * np.exp(-1j * K * d)


@pytest.mark.parametrize("pol", ["V", "H"])
def test_metal_floor_two_ray_interference_matches_the_image_method(pol):
    floor = plate_mesh((0, 0, 0), (1, 0, 0), (0, 1, 0), 30.0, 30.0)
    patches, prov = _room([floor], spacing=1.0)
    x = np.linspace(1.0, 10.0, 60)
    tx = np.tile([[0.0, 0.3, 1.5]], (len(x), 1))
    rx = np.stack([x, np.full_like(x, -0.4), np.full_like(x, 1.0)], 1)
    paths = trace_room_paths(tx, rx, np.full(len(x), F), patches, prov, polarisation=pol, max_order=1)
    got = _field(paths, patches, [METAL])
    # closed form: direct + image source, the reflected field vector -(I - 2 n n^T) e_T
    n = np.array([0.0, 0.0, 1.0])
    d0 = rx - tx
    img = tx * [1, 1, -1]
    d1 = rx - img
    k0u = d0 / np.linalg.norm(d0, axis=1, keepdims=True)
    k1u = d1 / np.linalg.norm(d1, axis=1, keepdims=True)
    k_dep = k1u * [1, 1, -1]                                     # the real ray leaves Tx downward
    e_t = antenna_polarisation(k_dep, pol)
    e_ref = -(e_t - 2 * (e_t @ n)[:, None] * n)
    direct = _free(np.linalg.norm(d0, axis=1)) * (antenna_polarisation(k0u, pol) * antenna_polarisation(k0u, pol)).sum(1)
    refl = _free(np.linalg.norm(d1, axis=1)) * (antenna_polarisation(k1u, pol) * e_ref).sum(1)
    want = direct + refl
    assert np.max(np.abs(20 * np.log10(np.abs(got) / np.abs(want)))) < 1e-6
    assert np.max(np.abs(np.angle(got / want))) < 1e-6
    assert 20 * np.log10(np.abs(want).max() / np.abs(want).min()) > 10     # the test spans interference nulls


def test_dielectric_wall_in_a_horizontal_plane_is_pure_te():
    wall = plate_mesh((3.0, 0, 1.5), (0, 1, 0), (0, 0, 1), 20.0, 20.0)
    patches, prov = _room([wall], spacing=1.0)
    y = np.linspace(-4.0, 4.0, 9)
    tx = np.stack([np.zeros_like(y), np.zeros_like(y), np.full_like(y, 1.5)], 1)
    rx = np.stack([np.full_like(y, 1.0), y, np.full_like(y, 1.5)], 1)
    paths = trace_room_paths(tx, rx, np.full(len(y), F), patches, prov, polarisation="V", max_order=1)
    eps, sig = itu_law("concrete", F)
    eta = complex(permittivity(float(eps), float(sig), F))
    one = paths.order == 1
    assert int(one.sum()) == len(y)
    got = _field(paths, patches, [eta], [0.2]) - _free(np.linalg.norm(rx - tx, axis=1))
    img = tx.copy()
    img[:, 0] = 6.0
    d = np.linalg.norm(rx - img, axis=1)
    cos = np.abs(rx[:, 0] - img[:, 0]) / d
    r_te = fresnel(eta, cos, K, 0.2)[0].numpy()
    want = r_te * _free(d)         # (e_T . s) (e_R . s) = 1 for V in a horizontal plane (s along +-z)
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("extent", ["disks", "tiles"])
@pytest.mark.parametrize("spacing", [0.3, 0.12])
def test_wall_between_antennas_applies_the_slab_transmission_once(spacing, extent):
    wall = plate_mesh((0.0, 0, 1.5), (0, 1, 0), (0, 0, 1), 6.0, 3.0)
    patches, prov = _room([wall], spacing=spacing, extent=extent)
    ang = np.radians([0.0, 20.0, 40.0])
    tx = np.stack([np.full(3, -2.0), np.zeros(3), np.full(3, 1.5)], 1)
    rx = np.stack([2.0 * np.cos(ang) * 0 + 2.0, 4.0 * np.tan(ang), np.full(3, 1.5)], 1)
    paths = trace_room_paths(tx, rx, np.full(3, F), patches, prov, polarisation="V", max_order=1)
    assert (paths.order == 0).sum() == 3 and (paths.order > 0).sum() == 0      # no reflection to the far side
    eps, sig = itu_law("concrete", F)
    eta = complex(permittivity(float(eps), float(sig), F))
    got = _field(paths, patches, [eta], [0.2])
    d = np.linalg.norm(rx - tx, axis=1)
    cos = np.abs((rx - tx)[:, 0]) / d
    t_te = slab_transmission(eta, cos, K, 0.2)[0].numpy()
    np.testing.assert_allclose(got, t_te * _free(d), rtol=1e-9, atol=1e-14)
    loss_db = -20 * np.log10(np.abs(t_te[0]))
    assert 5.0 < loss_db < 30.0                                   # a 20 cm concrete wall costs over 5 dB
    blocked = _field(paths, patches, [METAL], [0.2])
    assert np.all(np.abs(blocked) < 1e-6 * np.abs(_free(d)))


@pytest.mark.parametrize("extent", ["disks", "tiles"])
def test_no_reflection_from_an_opening_in_the_wall(extent):
    left = plate_mesh((0.0, -2.0, 1.5), (0, 1, 0), (0, 0, 1), 2.0, 3.0)     # a wall with a 2 m gap in the middle
    right = plate_mesh((0.0, 2.0, 1.5), (0, 1, 0), (0, 0, 1), 2.0, 3.0)
    patches, prov = _room([left, right], spacing=0.2, extent=extent)
    y = np.array([-2.0, 0.0, 2.0])
    tx = np.stack([np.full(3, 2.0), y, np.full(3, 1.5)], 1)
    rx = np.stack([np.full(3, 1.0), y, np.full(3, 1.5)], 1)
    paths = trace_room_paths(tx, rx, np.full(3, F), patches, prov, max_order=1)
    hit = np.zeros(3, int)
    np.add.at(hit, paths.link[paths.order == 1].numpy(), 1)
    assert hit.tolist() == [1, 0, 1]


def test_paths_with_more_interactions_than_allowed_are_dropped():
    floor = plate_mesh((0.0, 0.0, 0.0), (1, 0, 0), (0, 1, 0), 30.0, 30.0)
    walls = [plate_mesh((x, 0.0, 1.5), (0, 1, 0), (0, 0, 1), 6.0, 3.0) for x in (-1.0, 0.0, 1.0)]
    patches, prov = _room([floor, *walls], spacing=0.5)
    tx, rx = np.array([[-2.0, 0.0, 1.5]]), np.array([[2.0, 0.0, 1.0]])
    # the direct path crosses the three partitions (3 interactions); the floor reflection crosses them too (4)
    kept = {}
    for n in (2, 3, 4, 8):
        paths = trace_room_paths(tx, rx, np.array([F]), patches, prov, max_order=1, max_interactions=n)
        kept[n] = sorted(zip(paths.order.tolist(), (paths.kind > 0).sum(1).tolist()))
    assert kept == {2: [], 3: [(0, 3)], 4: [(0, 3), (1, 4)], 8: [(0, 3), (1, 4)]}


def test_metal_corner_second_order_path():
    a = plate_mesh((0.0, 2.0, 1.5), (0, 1, 0), (0, 0, 1), 4.0, 3.0)          # plane x = 0
    b = plate_mesh((2.0, 0.0, 1.5), (1, 0, 0), (0, 0, 1), 4.0, 3.0)          # plane y = 0
    patches, prov = _room([a, b], spacing=0.25)
    tx = np.array([[1.0, 2.5, 1.5]])
    rx = np.array([[2.5, 1.0, 1.5]])
    paths = trace_room_paths(tx, rx, np.array([F]), patches, prov, polarisation="V", max_order=2)
    # Tx -> x=0 -> y=0 -> Rx meets the walls at (0, 1.5) and (1.5, 0); the other order would need
    # (0, -1.5), beyond the wall
    assert sorted(paths.order.tolist()) == [0, 1, 1, 2]
    two = (paths.order == 2).numpy()
    img = tx * [-1, -1, 1]                                      # imaged in both planes
    d = np.linalg.norm(rx - img)
    np.testing.assert_allclose(paths.length_m.numpy()[two], [d], rtol=1e-12)
    # V in a horizontal plane: TE at both walls, (-1)(-1) for metal, and e_R . e_T = 1 for V
    lab = torch.as_tensor(patches.label)
    eta = torch.full((2, 1), METAL, dtype=torch.complex128)[lab]
    sel = torch.as_tensor(np.flatnonzero(two))
    sub = type(paths)(1, paths.link[sel], *(t[sel] for t in (paths.length_m, paths.gain, paths.order, paths.e_tx,
                      paths.e_rx, paths.kind, paths.patch, paths.cos, paths.s, paths.p_in, paths.p_out)), paths.freq_hz)
    got = sub.field(eta, None, torch.zeros(patches.num, dtype=torch.float64)).numpy()[0]
    np.testing.assert_allclose(got, _free(d), rtol=1e-9)


def _corner_cube_triple_paths(tx, rx, size):
    """Independent image method for three metal plates on x = 0, y = 0, z = 0 (each covering [0, size]^2 of
    its plane): the reflection sequences (axis order) whose three points lie on their plates, in order."""
    import itertools

    found = []
    for seq in itertools.permutations(range(3)):
        images = [np.array(tx, float)]
        for ax in seq:
            im = images[-1].copy()
            im[ax] = -im[ax]
            images.append(im)
        pts, end, ok = [], np.array(rx, float), True
        for level in (2, 1, 0):                       # backwards from the receiver
            ax, im = seq[level], images[level + 1]
            f = end[ax] / (end[ax] - im[ax])          # where end -> image crosses the plane
            p = end + f * (im - end)
            ok &= bool(0.0 < f < 1.0 and p.min() >= -1e-9 and p.max() <= size)
            pts.append(p)
            end = p
        if ok:
            found.append((seq, np.linalg.norm(np.array(rx) - images[-1])))
    return found


def test_metal_corner_cube_third_order_paths():
    size = 4.0
    plates = [plate_mesh((0.0, size / 2, size / 2), (0, 1, 0), (0, 0, 1), size, size),    # x = 0
              plate_mesh((size / 2, 0.0, size / 2), (1, 0, 0), (0, 0, 1), size, size),    # y = 0
              plate_mesh((size / 2, size / 2, 0.0), (1, 0, 0), (0, 1, 0), size, size)]    # z = 0
    patches, prov = _room(plates, spacing=0.25, extent="tiles")
    tx = np.array([[1.5, 1.5, 1.5], [1.5, 1.5, 1.5]])
    rx = np.array([[2.5, 1.2, 0.8], [1.0, 1.2, 2.0]])
    paths = trace_room_paths(tx, rx, np.full(2, F), patches, prov, polarisation="V", max_order=3,
                             higher_order_min_area_m2=1.0, third_order_min_area_m2=1.0)
    lab = torch.as_tensor(patches.label)
    eta = torch.full((3, 1), METAL, dtype=torch.complex128)[lab]
    for k in range(2):
        # a corner cube has one valid ordering per link; the image of every ordering is -tx
        (seq, d), = _corner_cube_triple_paths(tx[k], rx[k], size)
        three = ((paths.order == 3) & (paths.link == k)).numpy()
        assert three.sum() == 1
        q = int(np.flatnonzero(three)[0])
        assert tuple(patches.label[paths.patch[q, paths.kind[q] == 1].numpy()]) == seq
        np.testing.assert_allclose(paths.length_m.numpy()[q], d, rtol=1e-12)
        # a perfect conductor maps E -> -(I - 2 n n^T) E at each plate; over three orthogonal plates the product
        # is the identity and the ray leaves reversed, so e_R . E = 1 for V: the free-space field at the image
        # distance
        sel = torch.tensor([q])
        sub = type(paths)(1, torch.zeros(1, dtype=torch.int64), *(t[sel] for t in (
            paths.length_m, paths.gain, paths.order, paths.e_tx, paths.e_rx, paths.kind, paths.patch, paths.cos,
            paths.s, paths.p_in, paths.p_out)), paths.freq_hz[k:k + 1])
        got = sub.field(eta, None, torch.zeros(patches.num, dtype=torch.float64)).numpy()[0]
        np.testing.assert_allclose(got, _free(d), rtol=1e-9)
    # third order only off patches of at least third_order_min_area_m2
    none = trace_room_paths(tx, rx, np.array([F]), patches, prov, max_order=3, higher_order_min_area_m2=1.0,
                            third_order_min_area_m2=size * size + 1.0)
    assert not (none.order == 3).any()


def test_tabulated_coefficients_equal_the_exact_evaluation():
    from rfir_stages.model.physical import MaterialParams
    from rfir_stages.model.room import RoomLinks

    floor = plate_mesh((2.0, 2.0, 0.0), (1, 0, 0), (0, 1, 0), 6.0, 6.0)
    wall = plate_mesh((0.0, 2.0, 1.5), (0, 1, 0), (0, 0, 1), 6.0, 3.0)
    pane = plate_mesh((2.0, 0.5, 1.2), (1, 0, 0), (0, 0, 1), 1.0, 1.0)          # crossed by some direct paths
    patches, prov = _room([floor, wall, pane], spacing=0.25)
    rng = np.random.default_rng(0)
    tx = rng.uniform([0.5, -1.0, 0.5], [4.0, 4.0, 2.5], (40, 3))
    rx = rng.uniform([0.5, -1.0, 0.5], [4.0, 4.0, 2.5], (40, 3))
    paths = trace_room_paths(tx, rx, np.full(40, F), patches, prov, max_order=2, higher_order_min_area_m2=0.5)
    assert (paths.kind == 2).any() and (paths.order == 2).any()
    params = MaterialParams(3, eps_r=4.0, sigma_1ghz=0.05, scattering=0.2, thickness_m=0.1)
    params.set_values(2, eps_r=6.3, sigma_1ghz=0.003, thickness_m=0.006)
    with torch.no_grad():
        vals = params.values()
        lab = torch.as_tensor(patches.label)
        links = RoomLinks(paths, None, lab, 3)
        fast = links.power(vals)[:, 0].numpy()
        exact = np.abs(paths.field(vals.eta(torch.tensor([F]))[lab], vals.thickness_m[lab],
                                   vals.scattering[lab]).numpy()) ** 2
    assert np.max(np.abs(10 * np.log10(fast / exact))) < 0.01


def test_diffuse_weights_equal_the_direct_lambertian_sum():
    from rfir_stages.model.room_diffuse import CellCrossings, diffuse_cells, diffuse_terms

    floor = plate_mesh((0.0, 0.0, 0.0), (1, 0, 0), (0, 1, 0), 4.0, 4.0)
    patches, prov = _room([floor], spacing=0.25)
    geom = prov.geom
    areas = surfel_areas(geom.means, geom.log_scales, geom.rotations, geom.normals).numpy()
    cells = diffuse_cells(geom.means.numpy(), areas, patches, np.zeros(patches.num, np.int64), 1.0)
    assert abs(cells.area.sum() - 16.0) < 0.8 and len(cells.area) >= 16     # surfel areas: within 5 % of the plate
    tx = np.array([[0.3, -0.2, 1.8], [-1.0, 1.0, 2.5]])
    rx = np.array([[1.2, 0.9, 1.0], [1.5, -1.5, 0.7]])
    terms = diffuse_terms(tx, rx, np.full(2, F), cells, np.zeros(patches.num, np.int64), 1,
                          CellCrossings(cells, patches, prov))
    assert len(terms.obstructed.link) == 0                                  # nothing between antennas and floor
    eta = torch.tensor([[complex(5.24, -0.69)]], dtype=torch.complex128)
    got = terms.power(eta, torch.tensor([0.2]), torch.tensor([0.3], dtype=torch.float64)).numpy()
    want = []
    for t, r in zip(tx, rx):
        wi, wo = t - cells.centre, r - cells.centre
        di, do = np.linalg.norm(wi, axis=1), np.linalg.norm(wo, axis=1)
        ci, co = wi[:, 2] / di, wo[:, 2] / do
        r_te, r_tm = fresnel(eta[0, 0], ci, K, 0.2)
        g2 = 0.5 * (np.abs(r_te.numpy()) ** 2 + np.abs(r_tm.numpy()) ** 2)
        want.append(np.sum(0.09 * g2 * cells.area * ci * co * LAM ** 2 / (16 * math.pi ** 3 * di ** 2 * do ** 2)))
    np.testing.assert_allclose(got, want, rtol=2e-3)


def test_small_patches_pool_their_diffuse_cells():
    """Patches smaller than SMALL_PATCH_SHARE of a cell share cells by material, facing and voxel (scattered
    Gaussians off every plane would each be a cell); a large patch keeps its own; area is kept either way."""
    from rfir_stages.model.room_diffuse import SMALL_PATCH_SHARE, diffuse_cells

    floor = plate_mesh((1.0, 1.0, 0.0), (1, 0, 0), (0, 1, 0), 1.9, 1.9)              # inside the voxel [0, 2)^3
    tiles = [plate_mesh((x, y, 1.0 + 0.1 * k), (1, 0, 0), (0, 1, 0), 0.2, 0.2)       # 0.04 m^2 each, the same voxel
             for k, (x, y) in enumerate([(0.4, 0.4), (1.0, 0.4), (0.4, 1.0), (1.0, 1.0)])]
    patches, prov = _room([floor] + tiles, spacing=0.1)
    geom = prov.geom
    areas = surfel_areas(geom.means, geom.log_scales, geom.rotations, geom.normals).numpy()
    assert patches.num == 5 and sorted(patches.area)[-2] < SMALL_PATCH_SHARE * 2.0 ** 2
    mat = np.zeros(patches.num, np.int64)
    cells = diffuse_cells(geom.means.numpy(), areas, patches, mat, 2.0)
    big = int(np.argmax(patches.area))
    small = patches.surfel_patch != big
    assert np.isclose(cells.area.sum(), areas.sum())
    assert len(cells.area) == 2                                  # the floor's cell and one for the four tiles
    pooled = int(np.flatnonzero(cells.patch != big)[0])
    assert np.isclose(cells.area[pooled], areas[small].sum())
    assert np.allclose(cells.centre[pooled], (areas[small, None] * geom.means.numpy()[small]).sum(0) / areas[small].sum())
    assert abs(cells.normal[pooled] @ patches.normal[big]) > 0.999
    mat[patches.surfel_patch[np.flatnonzero(small)[0]]] = 1      # another material: a cell of its own
    assert len(diffuse_cells(geom.means.numpy(), areas, patches, mat, 2.0).area) == 3
    assert len(diffuse_cells(geom.means.numpy(), areas, patches, mat, 2.0, 0.0).area) == 5   # off: a cell per patch


@pytest.mark.parametrize("extent", ["disks", "tiles"])
def test_diffuse_power_through_a_wall_carries_its_slab_transmission(extent):
    """A floor lit through a wall from the transmitter's side: each cell's term is the unobstructed Lambertian
    term times the wall's |T|^2 = (|T_TE|^2 + |T_TM|^2) / 2 at its leg's crossing angle (slab formula); a
    metal wall passes no diffuse power; the transmission follows the wall's material during a fit."""
    from rfir_stages.model.room_diffuse import CellCrossings, diffuse_cells, diffuse_terms

    floor = plate_mesh((2.0, 0.0, 0.0), (1, 0, 0), (0, 1, 0), 4.0, 4.0)
    wall = plate_mesh((-0.5, 0.0, 1.5), (0, 1, 0), (0, 0, 1), 12.0, 7.0)
    patches, prov = _room([floor, wall], spacing=0.25, extent=extent)
    geom = prov.geom
    areas = surfel_areas(geom.means, geom.log_scales, geom.rotations, geom.normals).numpy()
    mat = np.asarray(patches.label, np.int64)                   # floor 0, wall 1
    cells = diffuse_cells(geom.means.numpy(), areas, patches, mat, 1.0)
    tx = np.array([[-1.5, 0.3, 1.5], [-2.0, -1.0, 1.0]])
    rx = np.array([[2.5, 1.0, 1.2], [1.0, -1.5, 0.8]])
    terms = diffuse_terms(tx, rx, np.full(2, F), cells, mat, 2, CellCrossings(cells, patches, prov))
    on_floor = cells.material == 0
    assert float(terms.weight.sum()) == 0.0 and len(terms.obstructed.link) >= 2 * on_floor.sum()   # all behind it
    s = torch.tensor([0.3, 0.0], dtype=torch.float64)
    floor_eta, wall_eta, wall_th = complex(5.24, -0.69), complex(4.0, -0.3), 0.05
    eta = torch.tensor([[floor_eta], [wall_eta]], dtype=torch.complex128)
    th = torch.tensor([0.2, wall_th], dtype=torch.float64)
    got = terms.power(eta, th, s).numpy()
    want = []
    for t, r in zip(tx, rx):
        c = cells.centre[on_floor]
        wi, wo = t - c, r - c
        di, do = np.linalg.norm(wi, axis=1), np.linalg.norm(wo, axis=1)
        ci, co = wi[:, 2] / di, wo[:, 2] / do
        r_te, r_tm = fresnel(eta[0, 0], ci, K, 0.2)
        g2 = 0.5 * (np.abs(r_te.numpy()) ** 2 + np.abs(r_tm.numpy()) ** 2)
        leg = cells.anchor_m[on_floor] - t
        cw = np.abs(leg[:, 0]) / np.linalg.norm(leg, axis=1)   # the wall's normal is x
        t_te, t_tm = slab_transmission(torch.tensor(wall_eta), torch.as_tensor(cw), K, wall_th)
        t2 = 0.5 * (np.abs(t_te.numpy()) ** 2 + np.abs(t_tm.numpy()) ** 2)
        assert 0.3 < t2.min() and t2.max() < 0.95               # a real loss, not a block
        lam = 0.09 * g2 * t2 * cells.area[on_floor] * ci * co * LAM ** 2 / (16 * math.pi ** 3 * di ** 2 * do ** 2)
        want.append(lam.sum())
    np.testing.assert_allclose(got, want, rtol=3e-3)
    metal = torch.tensor([[floor_eta], [complex(1.0, -1e9)]], dtype=torch.complex128)
    assert (terms.power(metal, th, s).numpy() < 1e-6 * np.asarray(want)).all()
    wall_eps = torch.tensor(4.0, dtype=torch.float64, requires_grad=True)   # gradients reach the wall's material
    p = terms.power(torch.stack([eta[0], torch.complex(wall_eps, torch.tensor(-0.3, dtype=torch.float64))[None]]),
                    th, s).sum()
    p.backward()
    assert wall_eps.grad is not None and float(wall_eps.grad) != 0.0
    per_link = terms.power(eta.expand(2, 2).contiguous(), th, s).numpy()   # eta per link (its frequency's)
    np.testing.assert_allclose(per_link, got, rtol=1e-12)
    sub = terms.select_links([1])                             # one link's entries, renumbered
    np.testing.assert_allclose(sub.power(eta, th, s).numpy(), got[1:], rtol=1e-12)


def test_a_coarse_wall_stays_one_patch_beside_finely_tiled_furniture():
    """Objects tiled at different spacings: the wall's surfels (1 m apart) are farther apart than the
    join radius of the fine furniture's median size, yet the wall is one patch and reflects as one."""
    from rfir_stages.geom.from_mesh import gaussians_from_mesh
    from rfir_stages.model.occlusion import FrozenGeometry

    wall = plate_mesh((0, 0, 1.5), (0, 1, 0), (0, 0, 1), 10.0, 3.0)
    parts = [gaussians_from_mesh(*wall, 1.0, labels=np.zeros(2, np.int64))]
    for i in range(12):   # twelve 0.5 m boxes' tops, each its own object, at 5 cm
        top = plate_mesh((2.0 + (i % 4), -2.0 + (i // 4), 0.75), (1, 0, 0), (0, 1, 0), 0.5, 0.5)
        parts.append(gaussians_from_mesh(*top, 0.05, labels=np.full(2, i + 1, np.int64)))
    g = {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}
    geom = FrozenGeometry(*(torch.as_tensor(g["gaussians/" + k]).double()
                            for k in ("means", "log_scales", "rotations", "normals")))
    labels = torch.as_tensor(g["gaussians/labels"], dtype=torch.int64)
    areas = surfel_areas(geom.means, geom.log_scales, geom.rotations, geom.normals)
    patches = build_patch_set(geom, areas, labels, coplanar_m=0.01, extent="disks")
    on_wall = np.unique(patches.surfel_patch[g["gaussians/labels"] == 0])
    assert len(on_wall) == 1
    assert patches.area[on_wall[0]] == pytest.approx(float(areas[labels == 0].sum()), rel=1e-9)
    assert patches.num == 13                                     # the wall and one patch per top
    # the wall reflects as the image method says: one first-order path off it for a link in front of it
    prov = make_provider("auto", geom)
    tx, rx = np.array([[-3.0, -1.0, 1.5]]), np.array([[-2.0, 2.0, 1.5]])
    paths = trace_room_paths(tx, rx, np.full(1, F), patches, prov, max_order=1)
    off_wall = (paths.order == 1) & (paths.patch[:, 0] == int(on_wall[0]))
    assert int(off_wall.sum()) == 1


@pytest.mark.parametrize("spacing", [0.07, 0.1])
def test_tiled_patches_end_where_their_surfaces_end(spacing):
    """extent "tiles" at furniture tilings (size / 12 of a 1.2 m desk): a desk top's 3 cm edge band stays
    3 cm tall (the "disks" extent widens it, which made grazing legs cross it falsely), a table top ends at
    its edges, a wall has no holes between tiles. (A 3 cm band tiled at 25 cm keeps gaps: the rectangles of long
    thin triangles do not cover it, and a closing wider than the band cannot fill them.)"""
    top = plate_mesh((0.0, 0.0, 0.75), (1, 0, 0), (0, 1, 0), 1.2, 0.6)
    band = plate_mesh((0.0, 0.3, 0.735), (1, 0, 0), (0, 0, 1), 1.2, 0.03)
    wall = plate_mesh((0.0, 3.0, 1.5), (1, 0, 0), (0, 0, 1), 6.0, 3.0)
    geom, labels, areas = _surfels_of([top, band, wall], spacing)
    tiles = build_patch_set(geom, areas, labels, coplanar_m=0.01, extent="tiles")
    disks = build_patch_set(geom, areas, labels, coplanar_m=0.01, extent="disks")
    assert tiles.num == disks.num == 3
    t, b, w = (int(np.flatnonzero(tiles.label == i)[0]) for i in range(3))
    over_band = np.array([[0.0, 0.3, 0.77], [0.3, 0.3, 0.70]])       # 2 cm above and 2 cm below the 3 cm band
    assert tiles.contains(np.full(2, b), np.array([[0.0, 0.3, 0.735], [0.4, 0.3, 0.73]])).all()
    assert not tiles.contains(np.full(2, b), over_band).any()
    near_band = np.array([[0.0, 0.3, 0.756], [0.3, 0.3, 0.714]])    # 6 mm above and below it
    assert not tiles.contains(np.full(2, b), near_band).any()
    assert disks.contains(np.full(2, b), near_band).any()
    inside = np.array([[0.56, 0.0, 0.75], [-0.56, 0.0, 0.75], [0.0, 0.26, 0.75], [0.0, -0.26, 0.75]])
    outside = np.array([[0.615, 0.0, 0.75], [-0.615, 0.0, 0.75], [0.0, 0.315, 0.75], [0.0, -0.315, 0.75]])
    assert tiles.contains(np.full(4, t), inside).all()
    assert not tiles.contains(np.full(4, t), outside).any()
    xs, zs = np.meshgrid(np.linspace(-2.96, 2.96, 120), np.linspace(0.04, 2.96, 60))
    grid = np.stack([xs.ravel(), np.full(xs.size, 3.0), zs.ravel()], 1)
    assert tiles.contains(np.full(len(grid), w), grid).all()         # no holes between tiles
    # a reflection off the table top exists only where its specular point lies on the table
    tx = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 2.0]])
    rx = np.array([[1.08, 0.0, 2.0], [1.23, 0.0, 2.0]])              # specular points at x = 0.54 and 0.615
    paths = trace_room_paths(tx, rx, np.full(2, F), tiles, make_provider("auto", geom), max_order=1)
    hit = np.zeros(2, int)
    np.add.at(hit, paths.link[(paths.order == 1) & (paths.patch[:, 0] == t)].numpy(), 1)
    assert hit.tolist() == [1, 0]


def test_a_small_face_ends_within_millimetres_of_its_edges():
    """A chair back's face (0.42 x 0.40 m, tiled at its size / 12): its patch holds points 3 mm inside every
    edge and none 3 mm outside, as a leg that passes the back's corner by millimetres must not cross it
    (`mesh-gaussians --rectangles`, an occupancy grid of a tenth of a tile)."""
    back = plate_mesh((5.26, 1.4, 0.65), (0, 1, 0), (0, 0, 1), 0.42, 0.40)
    geom, labels, areas = _surfels_of([back], 0.85 / 12, rectangles=True)
    tiles = build_patch_set(geom, areas, labels, coplanar_m=0.01, extent="tiles")
    assert tiles.num == 1
    s = np.linspace(-0.95, 0.95, 39)
    for d in (-0.003, 0.003):
        edges = np.concatenate([
            np.stack([np.full_like(s, 5.26), 1.4 + 0.21 * s, np.full_like(s, 0.85 + d)], 1),
            np.stack([np.full_like(s, 5.26), 1.4 + 0.21 * s, np.full_like(s, 0.45 - d)], 1),
            np.stack([np.full_like(s, 5.26), np.full_like(s, 1.61 + d), 0.65 + 0.2 * s], 1),
            np.stack([np.full_like(s, 5.26), np.full_like(s, 1.19 - d), 0.65 + 0.2 * s], 1)])
        inside = tiles.contains(np.zeros(len(edges), np.int64), edges)
        assert (not inside.any()) if d > 0 else inside.all()


def test_an_unknown_patch_extent_is_refused():
    from rfir_core.errors import ConfigError
    from rfir_stages.rf_fit.room_stage import room_config

    with pytest.raises(ConfigError, match="patch_extent"):
        room_config({"room": {"patch_extent": "hull"}})
    assert room_config({"room": {"patch_extent": "tiles"}})[0].patch_extent == "tiles"


def test_negative_small_reflections_and_no_kept_start_are_refused():
    from rfir_core.errors import ConfigError
    from rfir_stages.rf_fit.room_stage import room_config

    with pytest.raises(ConfigError, match="third_order_small_reflections"):
        room_config({"room": {"third_order_small_reflections": -1}})
    with pytest.raises(ConfigError, match="starts_kept = 0"):
        room_config({"room": {"starts_kept": 0}})
    settings, fit_cfg, _ = room_config({"room": {"starts_kept": 2, "third_order_small_reflections": 0}})
    assert (fit_cfg.starts_kept, settings.third_order_small_reflections) == (2, 0)


def test_fewer_interactions_than_reflections_are_refused():
    from rfir_core.errors import ConfigError
    from rfir_stages.rf_fit.room_stage import room_config

    with pytest.raises(ConfigError, match="max_interactions = 2 is below max_order = 3"):
        room_config({"room": {"max_order": 3, "max_interactions": 2}})
    assert room_config({"room": {"max_order": 3, "max_interactions": 3}})[0].max_interactions == 3


def test_room_settings_defaults_are_the_documented_config():
    """RoomSettings (what code and tests use) and configs/rf_fit.toml's [rf_fit.room] (what the CLI reads and
    documents) give every setting the same default."""
    from dataclasses import fields

    from rfir_core.config import load_defaults
    from rfir_stages.model.room import RoomSettings

    from rfir_stages.rf_fit.room_stage import room_config

    table = {k: v for k, v in load_defaults()["rf_fit"]["room"].items() if k != "sharing"}
    assert set(table) == {f.name for f in fields(RoomSettings)}
    assert table["max_interactions"] == "auto"            # data that record no simulator depth: the default
    parsed = room_config({"room": table})[0]
    assert {f.name: getattr(parsed, f.name) for f in fields(RoomSettings)} == \
        {f.name: getattr(RoomSettings(), f.name) for f in fields(RoomSettings)}


def test_auto_interactions_follow_the_simulated_depth():
    """max_interactions = "auto": the depth the file says the measurements were simulated to (max_order lowered
    to it if above); measured data (no simulator attributes) keep room_paths.MAX_INTERACTIONS; a number is
    taken as given; anything else is refused."""
    from types import SimpleNamespace

    from rfir_core.errors import ConfigError
    from rfir_stages.model.room_paths import MAX_INTERACTIONS
    from rfir_stages.rf_fit.room_stage import interactions_words, room_config, simulated_depth

    simulated = SimpleNamespace(free={"simulator@attrs": {"physics.max_depth": np.int64(3)}})
    measured = SimpleNamespace(free={})
    assert simulated_depth(simulated) == 3 and simulated_depth(measured) is None
    auto = {"room": {"max_interactions": "auto"}}
    s = room_config(auto, simulated_depth(simulated))[0]
    assert (s.max_interactions, s.max_order) == (3, 3)
    s = room_config(auto, 2)[0]
    assert (s.max_interactions, s.max_order) == (2, 2)
    assert room_config(auto, None)[0].max_interactions == MAX_INTERACTIONS
    assert room_config({"room": {"max_interactions": 8}}, 3)[0].max_interactions == 8
    assert "simulated to" in interactions_words(auto, 3) and "record no simulator depth" in interactions_words(auto, None)
    assert interactions_words({"room": {"max_interactions": 5}}, 3) == "rf_fit.room.max_interactions"
    for bad in ("eight", 2.5, True):
        with pytest.raises(ConfigError, match="max_interactions"):
            room_config({"room": {"max_interactions": bad}})



def test_a_metal_slab_gives_finite_gradients_in_the_diffuse_transmittance():
    """A metal's slab transmission underflows; |T|^2 taken with abs() then has a NaN gradient, which in a
    fit turns every material's parameters into NaN at the next step (the metal start of the optimiser)."""
    from rfir_stages.model.physical import MaterialParams
    from rfir_stages.model.room_diffuse import diffuse_transmittance

    params = MaterialParams(2, eps_r=1.5, sigma_1ghz=1e6, scattering=0.1, thickness_m=0.005)   # underflows to denormals
    params.set_values(0, eps_r=4.0, sigma_1ghz=0.05, thickness_m=0.1)
    freq = torch.tensor([F], dtype=torch.float64)
    vals = params.values()
    t2 = diffuse_transmittance(vals.eta(freq), vals.thickness_m, freq)
    assert float(t2[1].max()) < 1e-100 and float(t2[0].max()) > 0.05     # metal blocks, the dielectric not
    t2.sum().backward()
    for t in (params.t_eps, params.t_sig, params.t_th):
        assert torch.isfinite(t.grad).all()
    assert (params.t_eps.grad[0] != 0)


def test_abs2_equals_the_squared_modulus():
    from rfir_core.physics.materials import abs2

    z = torch.tensor([3 + 4j, 0j, 1e-170 + 1e-170j, 1e-310 + 0j, -2j], dtype=torch.complex128, requires_grad=True)
    np.testing.assert_allclose(abs2(z).detach().numpy(), np.abs(z.detach().numpy()) ** 2, rtol=1e-12)
    abs2(z).sum().backward()
    assert torch.isfinite(torch.view_as_real(z.grad)).all()


def _box_walls():
    """The six inward-facing plates of a closed 4 x 3 x 2.5 m box (floor at z = 0, a corner at the origin)."""
    return [plate_mesh((2.0, 1.5, 0.0), (1, 0, 0), (0, 1, 0), 4.0, 3.0),      # floor
            plate_mesh((2.0, 1.5, 2.5), (1, 0, 0), (0, -1, 0), 4.0, 3.0),     # ceiling
            plate_mesh((0.0, 1.5, 1.25), (0, 1, 0), (0, 0, 1), 3.0, 2.5),
            plate_mesh((4.0, 1.5, 1.25), (0, -1, 0), (0, 0, 1), 3.0, 2.5),
            plate_mesh((2.0, 0.0, 1.25), (-1, 0, 0), (0, 0, 1), 4.0, 2.5),
            plate_mesh((2.0, 3.0, 1.25), (1, 0, 0), (0, 0, 1), 4.0, 2.5)]


def test_reflection_paths_in_chunks_of_pairs_equal_one_pass(monkeypatch):
    """reflection_paths evaluates its (image row, link) pairs in chunks of PAIR_CHUNK (memory): any chunk size
    gives the same paths, in the same order, up to the third order in a closed box."""
    from rfir_stages.model import room_paths
    from rfir_stages.model.room_paths import reflection_paths

    walls = _box_walls()
    patches, _ = _room(walls, spacing=0.5)
    rng = np.random.default_rng(1)
    tx = np.repeat(rng.uniform([0.5, 0.5, 0.5], [3.5, 2.5, 2.0], (3, 3)), 20, axis=0)   # 3 transmitters x 20 links
    rx = rng.uniform([0.5, 0.5, 0.5], [3.5, 2.5, 2.0], (60, 3))
    cand = np.arange(patches.num)
    for order in (1, 2, 3):
        monkeypatch.setattr(room_paths, "PAIR_CHUNK", 10**9)
        whole = reflection_paths(tx, rx, patches, cand, order)
        monkeypatch.setattr(room_paths, "PAIR_CHUNK", 7)
        chunked = reflection_paths(tx, rx, patches, cand, order)
        assert len(whole[0]) > 0
        for a, b in zip(whole, chunked):
            np.testing.assert_array_equal(a, b)
    assert len(whole[0]) >= 60                   # third order in a box: paths for (nearly) every link


def test_third_order_with_one_small_reflection_is_the_filtered_full_enumeration():
    """third_order_small_reflections = 1: the third-order paths are exactly those of every patch of at least
    higher_order_min_area_m2 whose sequences hold at most one patch under third_order_min_area_m2 (two table tops
    in a closed box: table, ceiling, other table is left out), and some of them reflect off a table; with 0 none
    does."""
    from rfir_stages.model.room_paths import reflection_paths

    walls = _box_walls() + [
        plate_mesh((1.3, 1.5, 0.75), (1, 0, 0), (0, 1, 0), 1.0, 0.9),     # two table tops of 0.9 m^2
        plate_mesh((2.7, 1.5, 0.75), (1, 0, 0), (0, 1, 0), 1.0, 0.9)]
    patches, prov = _room(walls, spacing=0.3, extent="tiles")
    small = (patches.area >= 0.3) & (patches.area < 1.0)
    assert small.sum() == 2
    rng = np.random.default_rng(3)
    tx = np.repeat(rng.uniform([0.5, 0.5, 2.0], [3.5, 2.5, 2.3], (2, 3)), 40, axis=0)
    rx = rng.uniform([0.8, 1.1, 0.9], [3.2, 1.9, 1.2], (80, 3))
    paths = trace_room_paths(tx, rx, np.full(80, F), patches, prov, max_order=3, higher_order_min_area_m2=0.3,
                             third_order_min_area_m2=1.0, third_order_small_reflections=1)
    three = (paths.order == 3).numpy()
    got = {(int(lk), tuple(int(p) for p in pt[kd == 1])) for lk, pt, kd in
           zip(paths.link.numpy()[three], paths.patch.numpy()[three], paths.kind.numpy()[three])}
    cand = np.flatnonzero(patches.area >= 0.3)
    link, seq, _ = reflection_paths(tx, rx, patches, cand, 3)
    want = {(int(lk), tuple(int(p) for p in s)) for lk, s in zip(link, seq) if small[s].sum() <= 1}
    assert got == want
    assert any(small[list(s)].any() for _, s in got)
    assert len(want) < len({(int(lk), tuple(s)) for lk, s in zip(link, seq)})     # two small ones are left out
    none = trace_room_paths(tx, rx, np.full(80, F), patches, prov, max_order=3, higher_order_min_area_m2=0.3,
                            third_order_min_area_m2=1.0, third_order_small_reflections=0)
    assert not small[none.patch.numpy()[(none.order == 3).numpy()][none.kind.numpy()[(none.order == 3).numpy()] == 1]].any()
    # the paths that the setting adds, as the fit's first step leaves them out: without them the field is that of
    # the paths traced without the setting
    extra = paths.small_third_order(patches.area, 1.0)
    assert int(extra.sum()) == sum(small[list(q)].any() for _, q in got) > 0
    eta = np.full(int(patches.label.max()) + 1, 5.0 - 0.3j)
    np.testing.assert_allclose(_field(paths.select_paths(~extra), patches, eta, np.full(len(eta), 0.1), s=0.2),
                               _field(none, patches, eta, np.full(len(eta), 0.1), s=0.2), rtol=1e-9)


def _box_room_with_furniture():
    """A 4 x 3 x 2.5 m box, two table tops, a turned panel and a small plate low on a wall: patches and
    provider."""
    walls = _box_walls() + [
        plate_mesh((1.3, 1.5, 0.75), (1, 0, 0), (0, 1, 0), 1.0, 0.9),     # table tops
        plate_mesh((2.9, 0.8, 0.75), (1, 0, 0), (0, 1, 0), 0.8, 0.7),
        plate_mesh((3.2, 2.4, 1.4), (0.6, -0.8, 0), (0, 0, 1), 0.9, 1.0),  # a turned panel
        plate_mesh((0.02, 0.3, 0.5), (0, 1, 0), (0, 0, 1), 0.2, 0.2)]      # a small plate low on a wall
    return _room(walls, spacing=0.1, extent="tiles")


def test_bounding_spheres_hold_every_cell_of_their_patches():
    """PatchSet.bounding_spheres: every corner of every occupied cell lies within its patch's sphere."""
    patches, _ = _box_room_with_furniture()
    centre, radius = patches.bounding_spheres(np.arange(patches.num))
    for p in range(patches.num):
        rows, cols = patches.grid_shape[p]
        occ = patches.grid[patches.grid_offset[p]:patches.grid_offset[p] + rows * cols].reshape(rows, cols)
        i, j = np.nonzero(occ)
        assert len(i) > 0
        for di in (0, 1):
            for dj in (0, 1):
                a = patches.grid_origin[p, 0] + (i + di) * patches.cell_m[p]
                b = patches.grid_origin[p, 1] + (j + dj) * patches.cell_m[p]
                pts = patches.point[p] + a[:, None] * patches.u[p] + b[:, None] * patches.v[p]
                assert (np.linalg.norm(pts - centre[p], axis=1) <= radius[p] + 1e-9).all()


def test_sequences_dropped_before_pairing_hold_no_path(monkeypatch):
    """reflection_paths drops (transmitter, sequence) rows that no receiver can complete before pairing them with
    the receivers (_sequence_may_connect): orders 2 and 3 give the same paths as without the test, and it drops
    rows. A transmitter just above the floor has its image inside the floor's bounding sphere, and its path off
    the floor to the small plate on the wall beside it leaves that image more than 90 degrees from the floor's
    centre (a cone of the sphere's angular radius would miss it)."""
    from rfir_stages.model import room_paths
    from rfir_stages.model.room_paths import reflection_paths

    patches, _ = _box_room_with_furniture()
    rng = np.random.default_rng(7)
    tx = np.repeat(np.vstack([[0.8, 0.3, 0.1], rng.uniform([0.3, 0.3, 0.9], [3.7, 2.7, 2.3], (3, 3))]), 40, axis=0)
    rx = rng.uniform([0.2, 0.2, 0.2], [3.8, 2.8, 2.3], (160, 3))
    cand = np.arange(patches.num)
    test = room_paths._sequence_may_connect
    kept = []
    monkeypatch.setattr(room_paths, "_sequence_may_connect",
                        lambda images, seq, p: kept.append(test(images, seq, p)) or kept[-1])
    pruned = {o: reflection_paths(tx, rx, patches, cand, o) for o in (2, 3)}
    assert all(0 < k.sum() < len(k) for k in kept)
    monkeypatch.setattr(room_paths, "_sequence_may_connect", lambda images, seq, p: np.ones(len(seq), bool))
    for order in (2, 3):
        full = reflection_paths(tx, rx, patches, cand, order)
        assert len(full[0]) > 100
        for a, b in zip(full, pruned[order]):
            np.testing.assert_array_equal(a, b)


def test_paths_traced_a_group_of_transmitters_at_a_time_are_the_paths_traced_at_once(monkeypatch):
    """reflection_paths splits the distinct transmitters into groups (SOURCE_ROWS) so that a survey's hundred
    transmitter positions do not build every third-order sequence at once: one transmitter per group gives the
    same paths, points and order as all at once."""
    import rfir_stages.model.room_paths as rp

    size = 4.0
    plates = [plate_mesh((0.0, size / 2, size / 2), (0, 1, 0), (0, 0, 1), size, size),
              plate_mesh((size / 2, 0.0, size / 2), (1, 0, 0), (0, 0, 1), size, size),
              plate_mesh((size / 2, size / 2, 0.0), (1, 0, 0), (0, 1, 0), size, size)]
    patches, _ = _room(plates, spacing=1.0, extent="tiles")
    rng = np.random.default_rng(0)
    tx = np.repeat(rng.uniform(0.5, 3.5, (5, 3)), 3, axis=0)
    rx = rng.uniform(0.5, 3.5, (15, 3))
    cand = np.arange(patches.num)
    for order in (1, 2, 3):
        whole = rp.reflection_paths(tx, rx, patches, cand, order)
        monkeypatch.setattr(rp, "SOURCE_ROWS", 1)
        grouped = rp.reflection_paths(tx, rx, patches, cand, order)
        monkeypatch.undo()
        assert len(whole[0]) > 0
        for a, b in zip(whole, grouped):
            np.testing.assert_array_equal(a, b)
