"""Loads the compiled extension ``rfir_tracer._C`` and reports which back-end is in use."""
from __future__ import annotations

import torch

try:  # torch must be imported first: _C links against libc10 / libtorch
    from . import _C  # type: ignore[attr-defined]

    _IMPORT_ERROR: str | None = None
except ImportError as exc:  # pragma: no cover - only when the build is missing or broken
    _C = None
    _IMPORT_ERROR = str(exc)


def native():
    """The compiled module; raises RuntimeError with a fix when it is missing."""
    if _C is None:
        raise RuntimeError(
            "rfir_tracer._C is not built (" + str(_IMPORT_ERROR) + "); reinstall with "
            "`pip install --no-build-isolation -e .` from the repository root"
        )
    return _C


def backend_info() -> dict:
    """Describe the tracer back-end, for ``rfir info --tracer``.

    Returns a dict with ``backend`` ("cuda" when the extension has CUDA kernels and a GPU is
    visible, else "cpu-openmp"; None when the extension is not built), ``cuda_compiled``,
    ``cuda_available``, ``openmp_max_threads``, the k-buffer sizes, ``torch`` version and the
    extension path (or ``error`` when it failed to load).
    """
    info: dict = {"torch": torch.__version__, "cuda_available": torch.cuda.is_available()}
    if _C is None:
        info.update(backend=None, cuda_compiled=False, error=_IMPORT_ERROR)
        return info
    info.update(dict(_C.build_info()))
    use_cuda = info["cuda_compiled"] and info["cuda_available"]
    info["backend"] = "cuda" if use_cuda else "cpu-openmp"
    info["extension"] = _C.__file__
    return info
