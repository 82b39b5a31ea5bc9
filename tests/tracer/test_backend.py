"""backend_info() for `rfir info --tracer`."""
import torch

import rfir_tracer as rt


def test_backend_info_keys():
    info = rt.backend_info()
    for key in ("backend", "cuda_compiled", "cuda_available", "openmp_max_threads", "torch", "extension"):
        assert key in info, key
    assert info["backend"] in ("cpu-openmp", "cuda")
    assert info["openmp_max_threads"] >= 1
    if not torch.cuda.is_available():
        assert info["backend"] == "cpu-openmp"
