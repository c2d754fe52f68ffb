#!/usr/bin/env bash
# The deployment's tests (the last step of scripts/test.sh; docs/deploy.md). Idempotent;
# installs what it needs. No container registry is needed: the base image is made from
# Debian's packages (mmdebstrap) and the image built with buildah.
# 1. docker-compose.yml, the monitoring files and the Kubernetes manifests (rendered with
#    kustomize) against their schemas, offline, plus what the schemas cannot say;
# 2. the CPU image's runtime stages built from deploy/Dockerfile around an already built
#    b2tf ($B2TF_BINARY, else the newest of target/release/b2tf and target/debug/b2tf:
#    compiling inside the image takes ~10 min, deploy/scripts/build-image.sh does that),
#    checked (user, entrypoint, ports, volume, HEALTHCHECK, labels, no secrets) and run:
#    ready, onboard + estimate over loopback, SIGTERM, the store on the volume, a read-only
#    replica (deploy/test/smoke.sh), and with a read-only root file system (readonly-root.sh);
# 3. the GPU image's stages on the Debian base standing in for CUDA's (none can be pulled
#    here), checked the same way; the CUDA libraries it lacks are listed.
set -euo pipefail
cd "$(dirname "$0")/.."
start="$(date +%s)"
# The test ViT of gpu-standin.sh needs onnx and numpy, which scripts/setup.sh installs.
source scripts/env.sh
python3 -c 'import onnx, numpy' 2>/dev/null || { echo "onnx/numpy missing: run scripts/setup.sh first" >&2; exit 1; }
bash deploy/scripts/install-tools.sh
bash deploy/test/validate.sh .deps/deploy-tools
bash deploy/scripts/build-base.sh

# (ls fails when one of the two is missing, as release is in CI: `|| true`.)
binary="${B2TF_BINARY:-$( (ls -t target/release/b2tf target/debug/b2tf 2>/dev/null || true) | head -1)}"
[ -x "$binary" ] || { echo "no b2tf binary: build it first (cargo build) or set B2TF_BINARY" >&2; exit 1; }
ctx="$(mktemp -d)"
images=()
# The test images go; so do the untagged layers they leave (a new binary each run), while
# the base images stay for the next run.
cleanup() {
  for i in "${images[@]}"; do buildah rmi "$i" >/dev/null 2>&1 || true; done
  buildah rmi --prune >/dev/null 2>&1 || true
  rm -rf "$ctx"
}
trap cleanup EXIT
# The build context: the Dockerfile's own files and the binary, stripped as the full build
# strips it (the debug binary is ~400 MB with its symbols).
mkdir -p "$ctx/deploy" "$ctx/prebuilt"
cp -r deploy/Dockerfile deploy/image "$ctx/deploy/"
strip -o "$ctx/prebuilt/b2tf" "$binary"
echo "binary: $binary ($(du -h "$ctx/prebuilt/b2tf" | cut -f1) stripped)"

t="$(date +%s)"
images+=(localhost/b2tfpose:test-cpu)
bash deploy/scripts/buildah-build.sh "$ctx" localhost/b2tfpose:test-cpu cpu prebuilt --quiet >/dev/null
echo "CPU image built (runtime stages) in $(( $(date +%s) - t )) s"
bash deploy/test/check-image.sh localhost/b2tfpose:test-cpu
bash deploy/test/smoke.sh localhost/b2tfpose:test-cpu
bash deploy/test/readonly-root.sh localhost/b2tfpose:test-cpu

t="$(date +%s)"
images+=(localhost/b2tfpose:test-gpu)
bash deploy/scripts/buildah-build.sh "$ctx" localhost/b2tfpose:test-gpu gpu prebuilt --quiet \
  --build-arg CUDA_BASE=docker.io/library/debian:bookworm-slim >/dev/null
echo "GPU image built on the stand-in base in $(( $(date +%s) - t )) s"
bash deploy/test/check-image.sh localhost/b2tfpose:test-gpu
bash deploy/test/gpu-standin.sh localhost/b2tfpose:test-gpu
echo "deploy tests passed in $(( $(date +%s) - start )) s"
