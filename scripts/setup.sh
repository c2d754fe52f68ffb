#!/usr/bin/env bash
# Installs what b2tfpose needs on a fresh Debian machine with Rust: the Vulkan loader and
# Mesa's lavapipe software rasteriser (the renderer's adapter when there is no GPU).
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
command -v cargo >/dev/null || { echo "cargo not found: install Rust (https://rustup.rs)" >&2; exit 1; }
