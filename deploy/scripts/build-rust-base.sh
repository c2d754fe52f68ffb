#!/usr/bin/env bash
# A local stand-in for the Dockerfile's Rust builder image (rust:1.95-slim-bookworm) on
# machines that reach Debian's mirror but no container registry: the local Debian base
# (build-base.sh) plus gcc and libc6-dev (as the official slim image has) and this
# machine's Rust toolchain (rustc + cargo of `rustup` toolchain $RUST_TOOLCHAIN, docs left
# out), laid out like the official image (CARGO_HOME=/usr/local/cargo on PATH).
# Idempotent: does nothing when the image exists (FORCE=1 rebuilds).
set -euo pipefail
name="${RUST_BASE_IMAGE:-docker.io/library/rust:1.95-slim-bookworm}"
base="${BASE_IMAGE:-docker.io/library/debian:bookworm-slim}"
toolchain="$(rustc +"${RUST_TOOLCHAIN:-1.95.0}" --print sysroot)"
if [ -z "${FORCE:-}" ] && buildah inspect --type image "$name" >/dev/null 2>&1; then
  echo "builder image $name exists"; exit 0
fi
ctr="$(buildah from --pull=never "$base")"
trap 'buildah rm "$ctr" >/dev/null 2>&1 || true' EXIT
buildah run --isolation chroot "$ctr" -- sh -c 'apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends gcc libc6-dev ca-certificates >/dev/null && rm -rf /var/lib/apt/lists/*'
root="$(buildah mount "$ctr")"
mkdir -p "$root/usr/local/rust" "$root/usr/local/cargo/bin"
tar -C "$toolchain" --exclude=./share/doc -cf - . | tar -C "$root/usr/local/rust" -xf -
for tool in cargo rustc rustdoc; do ln -sf "/usr/local/rust/bin/$tool" "$root/usr/local/cargo/bin/$tool"; done
buildah umount "$ctr" >/dev/null
buildah config --env CARGO_HOME=/usr/local/cargo --env PATH=/usr/local/cargo/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin "$ctr"
echo "builder image $name: $(buildah run --isolation chroot "$ctr" -- rustc --version)"
buildah commit --quiet "$ctr" "$name" >/dev/null
