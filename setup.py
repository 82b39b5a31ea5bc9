"""Builds the Gaussian ray tracer extension (rfir_tracer._C) at install time.

The CPU back-end (OpenMP) is always built. The CUDA back-end is added only when a CUDA toolkit
and a CUDA build of torch are both present, so the same command works on a laptop and on a GPU box.
RFIR_NO_EXT=1 leaves the extension out (a wheel of the Python packages and their data in seconds, for
packaging checks; rfir_tracer then reports that it is not built).
"""
import glob
import os

from setuptools import find_namespace_packages, setup


def _packages():
    pkgs = ["rfir_core", "rfir_cli", "rfir_tracer", "rfir_stages"]
    pkgs += ["rfir_core._configs", "rfir_core._configs.recipes"]   # configs/ as package data (pyproject's package-dir)
    pkgs += ["rfir_core." + p for p in find_namespace_packages("src/rfir_core")]
    pkgs += ["rfir_cli." + p for p in find_namespace_packages("src/rfir_cli")]
    pkgs += ["rfir_stages." + p for p in find_namespace_packages("stages")]
    pkgs += ["rfir_tracer." + p for p in find_namespace_packages("ext/rfir_tracer")]
    return [p for p in pkgs if "__pycache__" not in p]


def _extensions():
    if os.environ.get("RFIR_NO_EXT") == "1":
        return [], {}
    import torch
    from torch.utils.cpp_extension import CUDA_HOME, BuildExtension, CppExtension, CUDAExtension

    here = os.path.dirname(os.path.abspath(__file__))
    cpp = sorted(glob.glob(os.path.join("ext", "csrc", "*.cpp")))
    cu = sorted(glob.glob(os.path.join("ext", "csrc", "*.cu")))
    if not cpp:
        return [], {}
    include = [os.path.join(here, "ext", "csrc")]
    cxx = ["-O3", "-fopenmp", "-std=c++17"]
    want_cuda = os.environ.get("RFIR_NO_CUDA") != "1"
    if want_cuda and cu and CUDA_HOME is not None and torch.version.cuda is not None:
        ext = CUDAExtension(
            "rfir_tracer._C", cpp + cu, include_dirs=include,
            define_macros=[("RFIR_WITH_CUDA", "1")],
            extra_compile_args={"cxx": cxx, "nvcc": ["-O3", "-std=c++17"]},
            extra_link_args=["-fopenmp"],
        )
    else:
        ext = CppExtension(
            "rfir_tracer._C", cpp, include_dirs=include,
            extra_compile_args={"cxx": cxx}, extra_link_args=["-fopenmp"],
        )
    return [ext], {"build_ext": BuildExtension.with_options(use_ninja=True)}


ext_modules, cmdclass = _extensions()
setup(packages=_packages(), ext_modules=ext_modules, cmdclass=cmdclass)
