#!/usr/bin/env bash
# On a machine with an NVIDIA GPU, a CUDA toolkit and a CUDA build of torch: build the tracer extension
# in place with its CUDA back-end, run the tracer tests (CPU and CUDA-vs-CPU), and benchmark the CUDA
# path beside the CPU path on the same machine. Logs and JSON go to the folder given (default
# cuda_check/). Needs only torch, pytest, hypothesis and psutil (not the whole rfir install).
# Usage: bash scripts/cuda_check.sh [OUTDIR]
set -uo pipefail
out=${1:-cuda_check}
mkdir -p "$out"
py=${PYTHON:-python3}
export TORCH_CUDA_ARCH_LIST=${TORCH_CUDA_ARCH_LIST:-9.0} MAX_JOBS=${MAX_JOBS:-16} PYTHONPATH=ext PYTHONUNBUFFERED=1
nvidia-smi -L; nvcc --version | tail -2
$py -c "import torch; print('torch', torch.__version__, 'cuda', torch.version.cuda)"
rm -f ext/rfir_tracer/_C*.so
start=$(date +%s)
$py setup.py build_ext --inplace >"$out/build.log" 2>&1 || { tail -40 "$out/build.log"; exit 1; }
echo "build: $(( $(date +%s) - start )) s"
$py -c "import rfir_tracer as rt; print(rt.backend_info())"
$py -m pytest -q -p no:cacheprovider tests/tracer 2>&1 | tee "$out/tests.log" | tail -15
$py bench/bench_tracer.py --device cuda --gaussians 10000,100000,1000000 --sizes 256,1024 \
    --out "$out/tracer_cuda.json" 2>&1 | tee "$out/bench_cuda.log" | grep -v '^done'
$py bench/bench_tracer.py --device cpu --no-open3d --ref-rays 0 --reps 3 --gaussians 10000,100000 --sizes 256 \
    --out "$out/tracer_cpu.json" 2>&1 | tee "$out/bench_cpu.log" | grep -v '^done'
