"""Split protocols, the ablation switches, the diffuse term, and the prediction speed-ups (batched grid, culling)."""
import math

import numpy as np
import pytest
import torch

from rfir_cli.errors import ConfigError, StageError
from rfir_stages.rf_fit.antennas import AntennaPattern
from rfir_stages.rf_fit.grid import local_grid, rays_toward_sphere, rays_toward_sphere_batch
from rfir_stages.rf_fit.occlusion import TracerOcclusion
from rfir_stages.geom import gaussians_from_mesh
from rfir_stages.rf_fit.render import Materials, RenderSettings, build_cache, link_geometry, render, render_power
from rfir_stages.rf_fit.splits import protocol_masks, split_rows, validation_rows

from .helpers import DEG, box_fields, geometry, radar, square

ISO = AntennaPattern("isotropic")


def _turntable(step_deg=1.0, ranges=(3.0,)):
    asp = np.radians(np.arange(0.0, 360.0, step_deg))
    a, r = np.meshgrid(asp, np.asarray(ranges, float), indexing="xy")
    split = (np.round(np.degrees(a)).astype(int) % 2).reshape(-1)
    return {"aspect_rad": a.reshape(-1), "range_m": r.reshape(-1), "split": split, "tx_pos": np.zeros((a.size, 3))}


def test_split_protocols_select_the_documented_rows():
    meas = _turntable()
    train, test = split_rows(meas, "every-10", "m.h5")
    assert len(train) == 36 and len(test) == 324
    assert np.all(np.round(np.degrees(meas["aspect_rad"][train])) % 10 == 0)
    train, test = split_rows(meas, "sector:315:45", "m.h5")          # wraps through 0
    deg = np.degrees(meas["aspect_rad"][test])
    assert len(test) == 90 and np.all((deg >= 315) | (deg < 45))
    train, test = split_rows(meas, "data", "m.h5")
    assert np.array_equal(train, np.flatnonzero(meas["split"] == 0))
    multi = _turntable(2.0, (2.0, 3.0, 4.0))
    train, test = split_rows(multi, "range:3", "m.h5")
    assert np.all(multi["range_m"][test] == 3.0) and not np.any(multi["range_m"][train] == 3.0)
    tr, te = protocol_masks(multi, "every-3", "m.h5")
    assert not np.any(tr & te) and np.all(tr | te)


@pytest.mark.parametrize("bad", ["every-1", "every-x", "sector:10", "lottery", "range:x"])
def test_unknown_or_malformed_protocols_are_config_errors(bad):
    with pytest.raises(ConfigError, match="split"):
        split_rows(_turntable(), bad, "m.h5")


def test_protocols_that_leave_nothing_are_refused():
    with pytest.raises(StageError, match="empty training split"):
        split_rows({**_turntable(), "split": np.ones(360, int)}, "data", "m.h5")
    with pytest.raises(StageError, match="holds out no row"):
        split_rows(_turntable(), "range:7", "m.h5")


def test_batched_grid_rays_equal_the_per_antenna_ones():
    torch.manual_seed(0)
    ld, lw = local_grid(2.0, True)
    o = torch.randn(40, 3, dtype=torch.float64) * 3
    ax = torch.randn(40, 3, dtype=torch.float64)
    c = torch.tensor([0.1, 0.2, 0.3], dtype=torch.float64)
    d, w, link = rays_toward_sphere_batch(o, ax, c, 0.5, ld, lw, chunk=7)
    ref = [rays_toward_sphere(o[m], ax[m], c, 0.5, ld, lw) for m in range(40)]
    assert torch.equal(d, torch.cat([r[0] for r in ref])) and torch.equal(w, torch.cat([r[1] for r in ref]))
    assert torch.equal(link, torch.cat([torch.full((len(r[0]),), m) for m, r in enumerate(ref)]))


def _materials(g):
    return Materials(torch.full((g,), 0.9, dtype=torch.float64), torch.linspace(1.0, 8.0, g, dtype=torch.float64),
                     torch.polar(torch.linspace(0.2, 0.9, g, dtype=torch.float64),
                                 torch.linspace(0, 3, g, dtype=torch.float64)))


def test_culling_stays_within_its_error_bound_and_skips_work():
    rel = 1e-3
    geom = geometry(box_fields(0.06, 0.02))
    links = radar(np.arange(0, 360, 30) * DEG + 0.1, 2.0, [2.4e9], height_m=0.02)
    m = _materials(geom.num)
    prov = TracerOcclusion(geom)
    full = render(build_cache(geom, links, ISO, ISO, prov, RenderSettings(grid_step_deg=2.0)), m)
    cached = build_cache(geom, links, ISO, ISO, prov, RenderSettings(grid_step_deg=2.0), cull=(m, rel))
    culled = render(cached, m)
    amp, lobe, _ = link_geometry(geom, links, ISO, ISO)
    bound = rel * (amp * lobe ** m.roughness[None] * m.opacity[None] * m.gamma.abs()[None]).sum(1)
    assert torch.all((culled - full).abs()[:, 0] <= bound + 1e-18)
    assert (cached.amp_geo == 0).sum() > (amp == 0).sum()             # something was skipped


def test_ablation_switches_drop_the_distance_and_phase_terms():
    geom = geometry(box_fields(0.1, 0.05))
    links = radar([0.3, 1.0], 2.0, [2.4e9])
    amp, _, path = link_geometry(geom, links, ISO, ISO)
    amp_flat, _, _ = link_geometry(geom, links, ISO, ISO, path_loss=False)
    d = (geom.means[None] - links.tx_m[:, None]).norm(dim=-1)
    r = (geom.means[None] - links.rx_m[:, None]).norm(dim=-1)
    ratio = amp_flat / amp.clamp(min=1e-300)
    lit = amp > 0
    expect = d * r / (d.mean(1, keepdim=True) * r.mean(1, keepdim=True))
    torch.testing.assert_close(ratio[lit], expect[lit])
    m = Materials(torch.ones(geom.num, dtype=torch.float64), torch.ones(geom.num, dtype=torch.float64),
                  torch.ones(geom.num, dtype=torch.complex128))
    no_phase = render(build_cache(geom, links, ISO, ISO, None, RenderSettings(visibility=False, phase=False)), m)
    amp_all, lobe, _ = link_geometry(geom, links, ISO, ISO)
    torch.testing.assert_close(no_phase[:, 0].real, (amp_all * lobe).sum(1))   # every Gaussian in phase
    assert torch.all(no_phase.imag.abs() < 1e-15)
    with_phase = render(build_cache(geom, links, ISO, ISO, None, RenderSettings(visibility=False)), m)
    assert torch.all(with_phase.abs() < no_phase.abs()) and math.isfinite(float(with_phase.abs().sum()))


def test_diffuse_term_adds_power_without_phase():
    # two plates a quarter wavelength apart in depth: their coherent echoes cancel (round trip lambda/2)
    lam = 299_792_458.0 / 2.4e9
    fields = [gaussians_from_mesh(*square(0.1, x), 0.05) for x in (0.0, -lam / 4)]
    geom = geometry({k: np.concatenate([f[k] for f in fields]) for k in fields[0]})
    links = radar([0.0], 3.0, [2.4e9], separation_m=0.0)
    g = geom.num
    cache = build_cache(geom, links, ISO, ISO, None, RenderSettings(visibility=False))
    one = torch.ones(g, dtype=torch.float64)
    coherent = Materials(one, one, one.to(torch.complex128))
    assert float(render_power(cache, coherent)[0, 0]) < 1e-3 * float(((cache.amp_geo * cache.lobe_base) .sum()) ** 2)
    diffuse = Materials(one, one, 0 * one.to(torch.complex128), diffuse=0.5 * one, diffuse_roughness=3 * one)
    expect = ((cache.amp_geo * 0.5 * cache.lobe_base**3) ** 2).sum()
    torch.testing.assert_close(render_power(cache, diffuse)[0, 0], expect)
    both = Materials(one, one, one.to(torch.complex128), diffuse=0.5 * one, diffuse_roughness=3 * one)
    torch.testing.assert_close(render_power(cache, both)[0, 0], render_power(cache, coherent)[0, 0] + expect)


def test_validation_rows_are_shaped_like_the_protocols_test():
    meas = _turntable()
    train, _ = split_rows(meas, "sector:45:135", "m.h5")
    deg = np.degrees(meas["aspect_rad"][train])
    val, how = validation_rows("sector:45:135", deg, meas["range_m"][train])
    got = np.sort(np.round(deg[val]).astype(int))
    assert len(val) == 27 and "next to the sector" in how                   # a tenth of 270 rows
    assert set(got) <= set(range(135, 150)) | set(range(30, 45))           # on both sides of the gap
    assert {135, 44} <= set(got)
    multi = _turntable(10.0, (2.0, 2.5, 3.0, 4.0))
    train, _ = split_rows(multi, "range:3", "m.h5")
    val, how = validation_rows("range:3", np.degrees(multi["aspect_rad"][train]), multi["range_m"][train])
    assert np.all(multi["range_m"][train][val] == 2.5) and len(val) == 36 and "2.5 m" in how
    val, how = validation_rows("every-10", np.arange(36.0) * 10, np.full(36, 3.0))
    assert np.array_equal(val, [5, 15, 25, 35]) and "every 10th" in how
