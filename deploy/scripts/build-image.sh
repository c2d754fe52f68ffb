#!/usr/bin/env bash
# The whole multi-stage build (b2tf compiled inside the image), timed, with buildah:
#   deploy/scripts/build-image.sh [cpu|gpu] [TAG] [buildah bud args, e.g. --no-cache]
# On a machine without registry access the Debian and Rust bases are made locally first
# (build-base.sh, build-rust-base.sh); the GPU flavour needs the CUDA base
# (nvidia/cuda:…-cudnn-runtime-ubuntu24.04) pulled or loaded beforehand. With docker:
#   docker build -f deploy/Dockerfile [--build-arg FLAVOR=gpu] -t b2tfpose:cpu .
set -euo pipefail
flavor="${1:-cpu}" tag="${2:-localhost/b2tfpose:$flavor}"
shift $(( $# < 2 ? $# : 2 ))
repo="$(cd "$(dirname "$0")/../.." && pwd)"
bash "$repo/deploy/scripts/build-base.sh"
buildah inspect --type image docker.io/library/rust:1.95-slim-bookworm >/dev/null 2>&1 || bash "$repo/deploy/scripts/build-rust-base.sh"
start="$(date +%s)"
bash "$repo/deploy/scripts/buildah-build.sh" "$repo" "$tag" "$flavor" build "$@"
echo "built $tag in $(( $(date +%s) - start )) s: $(buildah images --format '{{.Size}}' "$tag")"
