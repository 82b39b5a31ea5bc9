#!/usr/bin/env bash
# One-shot set-up for a fresh Debian 12 machine: system packages, a venv, rfir with its extension.
# Idempotent: re-running it only redoes what is missing. Used by `make setup` (and so by CI).
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
VENV=${VENV:-.venv}

# System packages (measured needs): libllvm19 for Dr.Jit/Sionna on the CPU (LLVM 15/16 abort the
# process), libusb-1.0-0 to import Open3D, libvulkan1 + mesa-vulkan-drivers for Open3D offscreen,
# ninja-build for fast extension builds.
APT_PKGS="libllvm19 libusb-1.0-0 libvulkan1 mesa-vulkan-drivers ninja-build"
missing=""
for p in $APT_PKGS; do dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"; done
if [ -n "$missing" ]; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  echo "setup: installing system packages:$missing"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq $missing
fi

[ -x "$VENV/bin/python" ] || "$PY" -m venv "$VENV"
PIP="$VENV/bin/python -m pip"
$PIP install -q --upgrade pip "setuptools>=77" wheel ninja
# torch is pinned: an unpinned torch makes pip fetch a multi-GB CUDA build.
$PIP install -q torch==2.13.0 numpy
# --no-build-isolation: build the extension against the torch just installed (not a fresh download).
$PIP install -q --no-build-isolation -e ".[all]"
"$VENV/bin/python" -c "import rfir_cli, rfir_stages; print('setup: rfir', rfir_cli.__version__, 'ready')"
