"""HitLists.footprint_sums: per group of rays and Gaussian, sums of w G and w G T-in-front (render's Tbar)."""
import pytest
import torch
from tracer_helpers import make_scene, random_scene

import rfir_tracer as rt
from rfir_tracer.result import HitLists


def _loop_reference(hits: HitLists, opacities, group_offsets, weight, margin, n, alpha_max=0.99):
    """Plain Python loops over rays and hits: the independent oracle."""
    m = len(group_offsets) - 1
    num = torch.zeros(m, n, dtype=torch.float64)
    den = torch.zeros(m, n, dtype=torch.float64)
    for k in range(m):
        for r in range(int(group_offsets[k]), int(group_offsets[k + 1])):
            ids, t, g = hits.of_ray(r)
            for h in range(len(ids)):
                tr = 1.0
                for j in range(h):
                    if float(t[j]) < float(t[h]) - margin:
                        tr *= 1.0 - min(float(opacities[ids[j]]) * float(g[j]), alpha_max)
                wg = float(weight[r]) * float(g[h])
                den[k, ids[h]] += wg
                num[k, ids[h]] += wg * tr
    return num, den


def _traced(seed=70, rays=90):
    s = random_scene(150, seed=seed, spread=0.8, scale=-1.8)
    g = torch.Generator().manual_seed(seed)
    o = torch.randn(rays, 3, generator=g, dtype=torch.float64) * 0.2 + torch.tensor([0.0, 0.0, -3.0])
    d = torch.nn.functional.normalize(torch.rand(rays, 3, generator=g, dtype=torch.float64) - 0.5
                                      + torch.tensor([0.0, 0.0, 1.0]), dim=1)
    res = rt.trace(make_scene(s), o, d, t_stop=0.0, return_hits=True)
    return s, res.hits


@pytest.mark.parametrize("margin", [0.0, 0.05])
def test_native_footprint_sums_match_loops_and_the_torch_path(margin):
    s, hits = _traced()
    assert hits.num_hits > 300
    n = s["means"].shape[0]
    a = torch.rand(n, generator=torch.Generator().manual_seed(1), dtype=torch.float64)
    groups = torch.tensor([0, 10, 10, 55, 90])                        # an empty group too
    w = torch.linspace(0.5, 2.0, 90, dtype=torch.float64)
    num, den = hits.footprint_sums(a, groups, w, margin)
    ref_num, ref_den = _loop_reference(hits, a, groups, w, margin, n)
    torch.testing.assert_close(den, ref_den, rtol=1e-12, atol=1e-15)
    torch.testing.assert_close(num, ref_num, rtol=1e-10, atol=1e-15)
    t_num, t_den = hits._footprint_sums_torch(a, groups, w, margin, 0.99)
    torch.testing.assert_close(t_num, num, rtol=1e-10, atol=1e-15)
    torch.testing.assert_close(t_den, den, rtol=1e-12, atol=1e-15)
    assert bool((num < den - 1e-9).any())                           # something is occluded
    assert torch.equal(den[1], torch.zeros(n, dtype=torch.float64))  # the empty group


def test_footprint_sums_refuse_inconsistent_offsets():
    s, hits = _traced(seed=71, rays=20)
    a = torch.rand(s["means"].shape[0], dtype=torch.float64)
    w = torch.ones(20, dtype=torch.float64)
    with pytest.raises(RuntimeError, match="group offsets"):
        hits.footprint_sums(a, torch.tensor([0, 5, 19]), w)
    with pytest.raises(RuntimeError, match="non-decreasing"):
        hits.footprint_sums(a, torch.tensor([0, 12, 5, 20]), w)
    with pytest.raises(RuntimeError, match="out of range"):
        hits.footprint_sums(a[:3], torch.tensor([0, 20]), w)
