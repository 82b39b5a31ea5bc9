"""A flat surface does not shadow itself near grazing (docs/physics.md section 8.6): the traced lit state of
surfels seen 1-3 degrees above their plane, against ray casting on the true mesh (po.visibility.Occluder).

The segment from a surfel toward the radar ends off the surfel's own surface (occlusion.segment_rays'
lift); before, it ran inside the thickness of the same surface's other Gaussians for several cm and
was absorbed by them. Only where a ray crosses an occluder within one surfel spacing of that occluder's
border may the traced state differ from the mesh's: there the Gaussians' coverage falls off (soft
borders, section 8.6), which no choice of segment end changes."""
import math

import numpy as np
import pytest
import torch

from rfir_stages.model.physical import PairSettings, traced_lit
from rfir_stages.po.visibility import Occluder
from rfir_stages.rf_fit.occlusion import BruteForceOcclusion, make_provider, segment_rays

from .helpers import plate_mesh, surfels

SPACING = 0.03
RANGE_M = 3.0


def _join(*meshes):
    verts, faces, n = [], [], 0
    for v, f in meshes:
        verts.append(v)
        faces.append(f + n)
        n += len(v)
    return np.concatenate(verts), np.concatenate(faces)


def _box(lo, hi):
    """A closed box [lo, hi] (m) as a triangle mesh: vertices [24, 3], faces [12, 3]."""
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    centre, size = (lo + hi) / 2, hi - lo
    parts = []
    for axis in range(3):
        u, w = np.eye(3)[(axis + 1) % 3], np.eye(3)[(axis + 2) % 3]
        for sign in (-1.0, 1.0):
            parts.append(plate_mesh(centre + sign * size[axis] / 2 * np.eye(3)[axis], u, w,
                                    size[(axis + 1) % 3], size[(axis + 2) % 3]))
    return _join(*parts)


def _direction(elevation_deg, azimuth_deg=0.0):
    e, a = math.radians(elevation_deg), math.radians(azimuth_deg)
    return np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])


def _states(verts, faces, direction, provider_kind="auto"):
    """(traced V [G] bool with the default settings, the mesh's exact V [G] bool, facing [G] bool, means [G, 3],
    ray directions [G, 3]) of every surfel from a radar at RANGE_M along `direction`."""
    geom, _ = surfels(verts, faces, SPACING)
    provider = make_provider(provider_kind, geom) if provider_kind != "brute-force" else BruteForceOcclusion(geom)
    antenna = torch.as_tensor(direction / np.linalg.norm(direction) * RANGE_M)
    traced = traced_lit(provider, antenna[None].expand(geom.num, 3), torch.arange(geom.num), PairSettings(),
                        geom.num).numpy() > 0.5
    p = geom.means.numpy()
    u = antenna.numpy()[None] - p
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    exact = Occluder(verts, faces).unoccluded(p + 1e-5 * u, u)
    facing = np.abs((u * geom.normals.numpy()).sum(1)) > 1e-6
    return traced, exact, facing, p, u


@pytest.mark.parametrize("elevation_deg", [1.0, 2.0, 3.0])
@pytest.mark.parametrize("azimuth_deg", [0.0, 40.0])
def test_two_coplanar_plates_near_grazing_are_lit_everywhere(elevation_deg, azimuth_deg):
    """Two tiled 0.3 m plates side by side in z = 0: every surfel lit, as the mesh says."""
    verts, faces = _join(plate_mesh((0.15, 0, 0), (1, 0, 0), (0, 1, 0), 0.3, 0.3),
                         plate_mesh((-0.15, 0, 0), (1, 0, 0), (0, 1, 0), 0.3, 0.3))
    traced, exact, facing, _, _ = _states(verts, faces, _direction(elevation_deg, azimuth_deg))
    assert facing.all() and exact.all()          # the reference: nothing stands above a flat plate
    assert traced.all(), f"{int((~traced).sum())} of {traced.size} surfels shadowed by their own plate"


@pytest.mark.parametrize("elevation_deg", [1.0, 2.0, 3.0])
def test_slab_near_grazing_lights_its_near_face_and_hides_its_far_face(elevation_deg):
    """A 0.3 x 0.3 m pane 6 mm thick (the trio's pane): its upper face is lit all over, its lower face
    stays hidden behind the upper one (and behind the pane's edge) except within one spacing of the edge."""
    verts, faces = _box((-0.15, -0.15, -0.003), (0.15, 0.15, 0.003))
    traced, exact, facing, p, _ = _states(verts, faces, _direction(elevation_deg, 17.0))
    upper, lower = p[:, 2] > 0.0029, p[:, 2] < -0.0029
    assert exact[upper].all() and not exact[lower].any()
    assert traced[upper].all(), f"{int((~traced[upper]).sum())} of {int(upper.sum())} upper surfels shadowed"
    inner = lower & (np.abs(p[:, :2]).max(1) < 0.15 - SPACING)
    assert inner.sum() > 0.5 * lower.sum()
    assert not traced[inner].any(), f"{int(traced[inner].sum())} lower surfels lit through the pane"


def _crossing_border_distance(p, u, half_y, z_top):
    """[G] m: where each ray p + s u (s > 0) crosses the plane x = 0, its distance to the border of the
    rectangle |y| <= half_y, 0 <= z <= z_top (inside or out); inf where it does not cross."""
    with np.errstate(divide="ignore", invalid="ignore"):
        s = -p[:, 0] / u[:, 0]
    y, z = p[:, 1] + s * u[:, 1], p[:, 2] + s * u[:, 2]
    inside = (np.abs(y) <= half_y) & (z >= 0) & (z <= z_top)
    dy, dz = np.abs(y) - half_y, np.maximum(-z, z - z_top)
    dist = np.where(inside, np.minimum(-dy, -dz), np.hypot(np.maximum(dy, 0), np.maximum(dz, 0)))
    return np.where(s > 0, dist, np.inf)


@pytest.mark.parametrize("elevation_deg", [1.0, 2.0, 3.0, 40.0, 60.0])
def test_fold_still_shadows_the_lying_plate(elevation_deg):
    """A dihedral of 3 mm sheets (the trio's metal one): the lying plate A (z in [0, 3 mm], x in [0, 0.3])
    seen from behind the standing plate B (x in [-3 mm, 0]): A's upper surfels are shadowed by B where the
    mesh says so, and lit where it says so, except where the ray crosses B's plane within one spacing of
    B's border."""
    verts, faces = _join(_box((0.0, -0.15, 0.0), (0.3, 0.15, 0.003)), _box((-0.003, -0.15, 0.0), (0.0, 0.15, 0.3)))
    direction = np.array([-math.cos(math.radians(elevation_deg)), 0.2, math.sin(math.radians(elevation_deg))])
    traced, exact, _, p, u = _states(verts, faces, direction)
    top = (p[:, 2] > 0.0029) & (p[:, 0] > 0.0)
    assert (~exact[top]).sum() > 0.5 * top.sum()          # most of A lies in B's shadow
    wrong = top & (traced != exact) & (_crossing_border_distance(p, u, 0.15, 0.3) > SPACING)
    assert not wrong.any(), (f"{int((wrong & traced).sum())} lit and {int((wrong & ~traced).sum())} shadowed "
                             f"against the mesh, away from B's border")


def test_brute_force_and_tracer_give_the_same_lifted_states():
    verts, faces = _join(_box((0.0, -0.15, 0.0), (0.3, 0.15, 0.003)), _box((-0.003, -0.15, 0.0), (0.0, 0.15, 0.3)))
    for direction in (_direction(1.5, 20.0), np.array([-1.0, 0.2, 0.05])):
        assert np.array_equal(_states(verts, faces, direction, "brute-force")[0], _states(verts, faces, direction)[0])


def test_segment_rays_lift_closed_form():
    """The lifted end: h = sqrt(2 ln(1 / alpha_min)) sqrt(n^T Sigma n) along the normal, on the origin's side,
    and the margin ignored along the segment shortened by h."""
    n = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]], dtype=torch.float64)
    cov = torch.diag(torch.tensor([4e-4, 1e-4, 1e-6], dtype=torch.float64)).expand(2, 3, 3)   # s_n = 1 mm
    ends = torch.zeros(2, 3, dtype=torch.float64)
    origins = torch.tensor([[3.0, 0.0, 0.1], [3.0, 0.0, -0.1]], dtype=torch.float64)   # above and below the plane
    o, d, t_max = segment_rays(origins, ends, 0.005, (n, cov, 1e-3))
    h = math.sqrt(2.0 * math.log(1e3)) * 1e-3
    lifted = o + d
    assert torch.allclose(lifted, torch.tensor([[0.0, 0.0, h], [0.0, 0.0, -h]], dtype=torch.float64), atol=1e-15)
    length = d.norm(dim=-1)
    assert torch.allclose(t_max, 1.0 - (0.005 - h) / length)
    _, _, t_big = segment_rays(origins, ends, 0.001, (n, cov, 1e-3))   # margin below h: nothing more ignored
    assert torch.equal(t_big, torch.ones(2, dtype=torch.float64))
    o0, d0, t0 = segment_rays(origins, ends, 0.005)
    assert torch.equal(o0 + d0, ends) and torch.allclose(t0, 1.0 - 0.005 / d0.norm(dim=-1))
