"""The occlusion tracer on a GPU answers as on the CPU; asking for a GPU that is not there fails loudly."""
import pytest
import torch

from rfir_stages.model.occlusion import BruteForceOcclusion, FrozenGeometry, make_provider


def _cloud(n=400, seed=3):
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=g, dtype=torch.float64)
    return FrozenGeometry(means=torch.rand(n, 3, generator=g, dtype=torch.float64) * 2 - 1,
                          log_scales=torch.full((n, 3), -2.5, dtype=torch.float64) + 0.3 * torch.rand(n, 3, generator=g,
                                                                                                        dtype=torch.float64),
                          rotations=q / q.norm(dim=1, keepdim=True),
                          normals=torch.nn.functional.normalize(torch.randn(n, 3, generator=g, dtype=torch.float64), dim=1))


def _queries(geom, m=600, seed=4):
    g = torch.Generator().manual_seed(seed)
    origins = torch.randn(m, 3, generator=g, dtype=torch.float64) * 3
    ids = torch.randint(0, geom.num, (m,), generator=g)
    opacity = torch.rand(geom.num, generator=g, dtype=torch.float64)
    return origins, ids, opacity


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_tracer_matches_cpu_tracer_and_the_oracle():
    geom = _cloud()
    origins, ids, opacity = _queries(geom)
    cpu, gpu = make_provider("tracer", geom, device="cpu"), make_provider("tracer", geom, device="cuda")
    assert gpu.name == "rfir_tracer (cuda)"
    v_cpu = cpu.segment_transmittance(origins, ids, 0.01, opacity)
    v_gpu = gpu.segment_transmittance(origins, ids, 0.01, opacity)
    assert v_gpu.device.type == "cpu"
    torch.testing.assert_close(v_gpu, v_cpu, rtol=1e-9, atol=1e-12)
    # the oracle multiplies every hit; the tracer stops below t_stop and drops alpha < alpha_min (CPU: 2e-3 apart)
    torch.testing.assert_close(v_gpu, BruteForceOcclusion(geom).segment_transmittance(origins, ids, 0.01, opacity),
                               rtol=0, atol=5e-3)
    dirs = torch.nn.functional.normalize(-origins, dim=1)
    h_cpu, h_gpu = cpu.ray_hits(origins, dirs), gpu.ray_hits(origins, dirs)
    assert torch.equal(h_gpu.query, h_cpu.query) and torch.equal(h_gpu.gaussian, h_cpu.gaussian)
    torch.testing.assert_close(h_gpu.t_m, h_cpu.t_m, rtol=1e-9, atol=1e-12)


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the refusal where no GPU exists")
def test_a_gpu_that_is_not_there_is_not_swapped_silently_for_the_cpu():
    geom = _cloud(50)
    with pytest.raises((AssertionError, RuntimeError)):   # CPU-only torch: AssertionError; no device: RuntimeError
        make_provider("auto", geom, device="cuda")
    assert make_provider("auto", geom, device="cpu").name == "rfir_tracer"
