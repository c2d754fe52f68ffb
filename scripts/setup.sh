#!/usr/bin/env bash
# Installs what b2tfpose needs on a fresh Debian machine with Rust: the Vulkan loader and
# Mesa's lavapipe software rasteriser (the renderer's adapter when there is no GPU), and,
# into .deps/python inside the checkout, the PyPI onnxruntime wheel (its shared library
# runs ONNX backbones; `--backbone onnx:PATH`) with onnx and numpy for the tools.
# Idempotent: installs only what is missing.
set -euo pipefail

need=()
for pkg in mesa-vulkan-drivers libvulkan1; do
  dpkg -s "$pkg" >/dev/null 2>&1 || need+=("$pkg")
done
if [ ${#need[@]} -gt 0 ]; then
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  echo "installing: ${need[*]}"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${need[@]}" >/dev/null
fi
# Debian's Python may come without pip.
if ! python3 -m pip --version >/dev/null 2>&1; then
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq python3-pip >/dev/null
fi
command -v cargo >/dev/null || { echo "cargo not found: install Rust (https://rustup.rs)" >&2; exit 1; }

# ONNX Runtime (CPU build) and the Python packages of tools/make_test_vit.py, pinned, in the
# checkout rather than system-wide (Debian's Python refuses system-wide pip installs).
ORT_VERSION=1.32.0
deps="$(cd "$(dirname "$0")/.." && pwd)/.deps/python"
if [ ! -f "$deps/onnxruntime-$ORT_VERSION.installed" ]; then
  echo "installing onnxruntime $ORT_VERSION, onnx and numpy into $deps"
  rm -rf "$deps"
  python3 -m pip install --quiet --disable-pip-version-check --target "$deps" "onnxruntime==$ORT_VERSION" "onnx==1.23.2" "numpy<3"
  touch "$deps/onnxruntime-$ORT_VERSION.installed"
fi
