#!/usr/bin/env bash
# The GPU image built on a stand-in base (Debian instead of CUDA's, which cannot be pulled
# here) and run without an NVIDIA driver, with the test ViT (tools/make_test_vit.py, needs
# onnx and numpy: scripts/setup.sh) as its ONNX backbone:
#   gpu-standin.sh IMAGE
# - on --device cpu, onnxruntime-gpu's library opens the model, and the start then stops at
#   the renderer: no Vulkan adapter without the driver, and no silent fallback to a CPU
#   rasteriser (the image has none);
# - on the image's own --device cuda:0, the CUDA provider asks for the CUDA 13 libraries,
#   which the real base (nvidia/cuda:13…-cudnn-runtime) supplies.
set -euo pipefail
image="$1"
repo="$(cd "$(dirname "$0")/../.." && pwd)"
models="$(mktemp -d)"
ctr="$(buildah from --pull=never "$image")"
trap 'buildah rm "$ctr" >/dev/null; rm -rf "$models"' EXIT
python3 "$repo/tools/make_test_vit.py" --out "$models" >/dev/null
chmod -R a+rX "$models"
serve() {
  buildah run --isolation chroot -v "$models:/models:ro" -e B2TF_BACKBONE=onnx:/models/model.onnx \
    -e B2TF_HTTP_ADDR=127.0.0.1:0 -e B2TF_GRPC_ADDR=127.0.0.1:0 "$@" "$ctr" -- timeout 120 b2tf serve 2>&1 || true
}
out="$(serve -e B2TF_DEVICE=cpu)"
grep -q "no GPU adapter found" <<<"$out" || { echo "$out" >&2; echo "expected: model loaded, then no adapter" >&2; exit 1; }
echo "GPU image, device cpu: ONNX model loaded by onnxruntime-gpu's library; renderer: no adapter without the NVIDIA driver (no CPU fallback)"
out="$(serve)"
grep -q "libonnxruntime_providers_cuda.so.*lib[a-zA-Z]*\.so\.13" <<<"$out" || { echo "$out" >&2; echo "expected: the CUDA provider asking for CUDA 13" >&2; exit 1; }
echo "GPU image, device cuda:0: the CUDA provider loads once CUDA 13 is there ($(grep -o 'lib[a-zA-Z]*\.so\.13' <<<"$out" | head -1) missing on the stand-in base)"
