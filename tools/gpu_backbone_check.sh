#!/usr/bin/env bash
# The GPU steps of docs/onnx_backbone.md, for a lent GPU machine that has PyTorch,
# transformers, onnx and CUDA but no internet and no onnxruntime-gpu, and that takes at
# most 64 MiB per call. Random weights in DINOv3's shapes (speed does not depend on them).
#
#   here:  tools/gpu_backbone_check.sh pack           # .gpu/: onnxruntime-gpu's libraries in
#                                                     # parts, a stripped b2tf, zstd, a manifest
#   there: tools/gpu_backbone_check.sh torch          # PyTorch timings of DINOv3's shapes
#          tools/gpu_backbone_check.sh export         # ViT-L/16 exports: fp32 and fp16, each with
#                                                     # plain and fused (-mha) attention
#          tools/gpu_backbone_check.sh stash          # keep the parts carried by this call
#          tools/gpu_backbone_check.sh bench          # b2tf on CUDA: backbone, estimate, serve
#          tools/gpu_backbone_check.sh bench-served   # the same with only the fp16 fused export
#                                                     # (after export-served: fewer minutes of GPU)
#          tools/gpu_backbone_check.sh serve-ab       # fp16 fused export only: the service with this
#                                                     # b2tf and with a carried .gpu/b2tf-baseline.zst
#          tools/gpu_backbone_check.sh other-devices  # ViT-L on TensorRT (refused without
#                                                     # libnvinfer) and on the CPU
#          tools/gpu_backbone_check.sh export-served  # only the fp16 fused export (for `threads`)
#          tools/gpu_backbone_check.sh threads        # the service with the global thread pool
#                                                     # capped (RAYON_NUM_THREADS): CPU per request
#                                                     # by thread group, rate, latency
#          tools/gpu_backbone_check.sh pca-speed      # stage times of ViT-L estimates at PCA auto
#                                                     # (192), 128, 96 and off; then the service
#
# Without ONNX Runtime (the embedded backbone; rendering on the GPU), one call:
#   here:  tools/gpu_backbone_check.sh pack-cell      # .gpu/: a stripped b2tf, zstd, the real frames
#   there: tools/gpu_backbone_check.sh cell           # tools/bench/real_rgbd_detect.sh, real_boxes.sh
#                                                     # (RGB, then with depth), objects_searched.sh
#
# Each stage keeps what it made in $STATE (default /tmp/b2tf-gpu), which lives as long as
# the machine stays warm; `bench` names any part that did not arrive.
set -euo pipefail
command -v zstd >/dev/null || { [ -x .gpu/zstd/zstd ] && export PATH="$PWD/.gpu/zstd:$PATH" LD_LIBRARY_PATH="$PWD/.gpu/zstd:${LD_LIBRARY_PATH:-}"; }
cd "$(dirname "$0")/.."
STATE="${STATE:-/tmp/b2tf-gpu}"
PART_MIB="${PART_MIB:-54}"
ORT_GPU_VERSION=1.31.1
mkdir -p "$STATE/parts" "$STATE/models"

pack() {
  local wheel_dir=.gpu/wheel
  mkdir -p "$wheel_dir"
  python3 -m pip download --quiet --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
    --platform manylinux_2_28_x86_64 -d "$wheel_dir" "onnxruntime-gpu==$ORT_GPU_VERSION"
  local tmp; tmp=$(mktemp -d)
  unzip -q -o -j "$wheel_dir"/onnxruntime_gpu-*.whl 'onnxruntime/capi/libonnxruntime*' -d "$tmp"
  tar -C "$tmp" -cf - . | zstd -19 -T0 --long=27 -q -o .gpu/ort.tar.zst -f
  rm -rf "$tmp" .gpu/ort-part-*
  split -b "${PART_MIB}M" -d -a 2 .gpu/ort.tar.zst .gpu/ort-part-
  rm .gpu/ort.tar.zst
  pack_b2tf
  (cd .gpu && sha256sum ort-part-* b2tf.zst > manifest)
  ls -la .gpu
}

# A stripped b2tf and this machine's zstd (the GPU image has none), with the libraries it links.
pack_b2tf() {
  mkdir -p .gpu
  cargo build --release --quiet --bin b2tf
  strip -o .gpu/b2tf target/release/b2tf
  zstd -19 -T0 -q -f --rm .gpu/b2tf -o .gpu/b2tf.zst
  mkdir -p .gpu/zstd && cp "$(command -v zstd)" .gpu/zstd/
  ldd "$(command -v zstd)" | awk '/=>/ {print $3}' | grep -v '/libc\.so' | xargs -r -I{} cp -L {} .gpu/zstd/
}

# The cell stage's carry: b2tf and the real frames (YCB-V with truth, the empty kitchen frames,
# one HOPE mesh as the object searched but absent), under the 64 MiB a call takes.
pack_cell() {
  local data="${DATA:-../shared/data}"
  pack_b2tf
  rm -rf .gpu/data && mkdir -p .gpu/data/hope/models
  cp -rL "$data/ycbv-rgbd" "$data/empty-rgbd" .gpu/data/
  cp -L "$data/hope/models/obj_000001".* .gpu/data/hope/models/
  python3 -c "import json,sys; i=json.load(open(sys.argv[1])); json.dump({'1': i['1']}, open(sys.argv[2], 'w'))" \
    "$data/hope/models/models_info.json" .gpu/data/hope/models/models_info.json
  du -sh .gpu
}

stash() {
  for f in .gpu/ort-part-* .gpu/b2tf.zst .gpu/b2tf-baseline.zst .gpu/manifest; do
    [ -f "$f" ] && cp "$f" "$STATE/parts/"
  done
  ls -la "$STATE/parts"
}

torch_stage() {
  nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
  PYTHONUNBUFFERED=1 python3 tools/time_vit_torch.py
}

export_stage() {
  local precision attention
  for precision in "" "-fp16"; do
    for attention in "" "-mha"; do
      python3 tools/export_backbone.py --random-init dinov3-vitl16 ${precision:+--fp16} ${attention:+--fused-attention} \
        --out "$STATE/models/vitl16$precision$attention.onnx"
    done
  done
}

export_served() {
  python3 tools/export_backbone.py --random-init dinov3-vitl16 --fp16 --fused-attention --out "$STATE/models/vitl16-fp16-mha.onnx"
}

cuda_library_path() {
  # The CUDA provider needs cuDNN, cuBLAS, cuFFT, cuRAND and the CUDA runtime: the image has
  # them as PyTorch's nvidia-* packages and under /usr/local/cuda.
  find /usr/local/cuda*/ /opt /usr/lib/x86_64-linux-gnu -xdev \( -name 'libcudnn.so.9' -o -name 'libcublasLt.so.13' \
    -o -name 'libcudart.so.13' -o -name 'libcufft.so.12' -o -name 'libcurand.so.10' -o -name 'libnvinfer.so.*' \) 2>/dev/null |
    xargs -r -n1 dirname | sort -u | paste -sd:
}

setup_b2tf() {
  (cd "$STATE/parts" && sha256sum -c --quiet manifest) || { echo "parts missing or damaged: carry them again (the machine went cold?)" >&2; exit 1; }
  mkdir -p "$STATE/ort"
  cat "$STATE"/parts/ort-part-* | zstd -d -q --long=27 | tar -C "$STATE/ort" -xf -
  zstd -d -q -f "$STATE/parts/b2tf.zst" -o "$STATE/b2tf" && chmod +x "$STATE/b2tf"
  export LD_LIBRARY_PATH="$STATE/ort:$(cuda_library_path):${LD_LIBRARY_PATH:-}"
  export B2TF_ORT_LIB="$STATE/ort/libonnxruntime.so.$ORT_GPU_VERSION"
  setup_renderer
  echo "missing libraries of the CUDA provider:"; ldd "$STATE/ort/libonnxruntime_providers_cuda.so" | grep "not found" || echo "  none"
}

# Rendering there goes through NVIDIA's Vulkan driver; the image lacks the loader, carried
# as Debian packages in .gl (the device tool's README says how to fetch them).
setup_renderer() {
  if compgen -G ".gl/*.deb" >/dev/null; then for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig; fi
  local icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
  [ -f "$icd" ] && export VK_DRIVER_FILES="$icd" __EGL_VENDOR_LIBRARY_FILENAMES=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
  return 0
}

# The detection and box paths with the embedded backbone and the renders on the GPU: the
# benchmarks docs/detection.md and docs/estimation.md report from 2 cores, on this machine.
# One object store serves them all (onboarded on first use, in the first script's first pass).
cell() {
  local data=.gpu/data out="$STATE/cell"
  zstd -d -q -f .gpu/b2tf.zst -o "$STATE/b2tf" && chmod +x "$STATE/b2tf"
  setup_renderer
  nvidia-smi --query-gpu=name,driver_version --format=csv,noheader
  echo "cores: $(nproc)"
  export B2TF_BIN="$STATE/b2tf"
  mkdir -p "$out/boxes" "$out/many"
  # First the renderer it found (and the stages of one estimate), so a run on llvmpipe shows.
  "$STATE/b2tf" bench estimate --images 3 --store "dir://$out/sample"
  tools/bench/real_rgbd_detect.sh "$data/ycbv-rgbd" "$data/empty-rgbd" "$out/detect"
  ln -sfn "$(realpath "$out/detect/objects")" "$out/boxes/objects"
  ln -sfn "$(realpath "$out/detect/objects")" "$out/many/objects"
  tools/bench/real_boxes.sh "$data/ycbv-rgbd" "$out/boxes"
  BOTH=--depth tools/bench/real_boxes.sh "$data/ycbv-rgbd" "$out/boxes"
  tools/bench/objects_searched.sh "$data/ycbv-rgbd" "$data/hope" "$out/many"
}

bench() {
  setup_b2tf
  local b2tf="$STATE/b2tf" m="$STATE/models"
  "$b2tf" bench backbone --onnx "$m/vitl16.onnx" --onnx "$m/vitl16-mha.onnx" --onnx "$m/vitl16-fp16.onnx" \
    --onnx "$m/vitl16-fp16-mha.onnx" --device cuda:0 --batches 1,8,32 --passes 5
  "$b2tf" bench estimate --backbone "onnx:$m/vitl16-fp16-mha.onnx" --device cuda:0 --images 5 --store "dir://$STATE/store"
  "$b2tf" bench serve --backbone "onnx:$m/vitl16-fp16-mha.onnx" --device cuda:0 --store "dir://$STATE/store" --clients 1,4,16 --requests 4 --protocols grpc
}

# `bench` for the served export alone (`export-served`), when the lease is short.
bench_served() {
  setup_b2tf
  local m="$STATE/models/vitl16-fp16-mha.onnx"
  nvidia-smi --query-gpu=name,driver_version --format=csv,noheader
  "$STATE/b2tf" bench backbone --onnx "$m" --device cuda:0 --batches 1,8,32 --passes 5
  "$STATE/b2tf" bench estimate --backbone "onnx:$m" --device cuda:0 --images 5 --store "dir://$STATE/store"
  "$STATE/b2tf" bench serve --backbone "onnx:$m" --device cuda:0 --store "dir://$STATE/store" --clients 1,4,16 --requests 4 --protocols grpc
}

# The service with two builds on one machine (this one, and an earlier one carried as
# .gpu/b2tf-baseline.zst): server CPU per request, the rate, latency. Needs only the fp16
# fused-attention export (`export_backbone.py ... --fp16 --fused-attention`).
serve_ab() {
  setup_b2tf
  local m="$STATE/models/vitl16-fp16-mha.onnx" b
  "$STATE/b2tf" bench backbone --onnx "$m" --device cuda:0 --batches 1,8,32 --passes 20
  "$STATE/b2tf" bench estimate --backbone "onnx:$m" --device cuda:0 --images 5 --store "dir://$STATE/store" | tail -3
  [ -f "$STATE/parts/b2tf-baseline.zst" ] || { echo "no baseline: carry .gpu/b2tf-baseline.zst (an earlier build, stripped and zstd-packed as pack does) and stash it" >&2; exit 1; }
  zstd -d -q -f "$STATE/parts/b2tf-baseline.zst" -o "$STATE/b2tf-baseline" && chmod +x "$STATE/b2tf-baseline"
  for b in b2tf-baseline b2tf; do
    echo "== $b"
    "$STATE/$b" bench serve --backbone "onnx:$m" --device cuda:0 --store "dir://$STATE/store" --clients 1,4,16 --requests 4 --protocols grpc
  done
}

# Where the server's CPU goes when the GPU runs the backbone: the same build with the global
# rayon pool at its default (one thread per core) and capped. The server runs as many
# estimates at once as there are clients, each spreading its parallel stages over the pool.
threads() {
  setup_b2tf
  local m="$STATE/models/vitl16-fp16-mha.onnx" n
  "$STATE/b2tf" bench estimate --backbone "onnx:$m" --device cuda:0 --images 5 --store "dir://$STATE/store"
  for n in default ${THREAD_CAPS:-4 1}; do
    echo "== RAYON_NUM_THREADS=$n"
    env $([ "$n" = default ] || echo "RAYON_NUM_THREADS=$n") "$STATE/b2tf" bench serve --backbone "onnx:$m" --device cuda:0 \
      --store "dir://$STATE/store" --clients 1,16 --requests 4 --protocols grpc
  done
}

# What fewer PCA dimensions save with ViT-L on CUDA (their accuracy needs the real weights):
# `bench estimate` applies each PCA in memory to the one cached full-width object, so only
# the first setting onboards. Then the service at the store's default PCA, for the rate.
pca_speed() {
  setup_b2tf
  local m="$STATE/models/vitl16-fp16-mha.onnx" p
  for p in ${PCA_SIZES:-auto 128 96 off}; do
    echo "== --pca $p"
    "$STATE/b2tf" bench estimate --backbone "onnx:$m" --device cuda:0 --images 5 --store "dir://$STATE/store" --pca "$p"
  done
  "$STATE/b2tf" bench serve --backbone "onnx:$m" --device cuda:0 --store "dir://$STATE/store" --clients 1,16 --requests 4 --protocols grpc
}

other_devices() {
  setup_b2tf
  local b2tf="$STATE/b2tf" m="$STATE/models"
  "$b2tf" bench backbone --onnx "$m/vitl16-fp16.onnx" --device tensorrt:0 --batches 1,8 --passes 3 || echo "(TensorRT: refused, above)"
  "$b2tf" bench backbone --onnx "$m/vitl16.onnx" --device cpu --batches 1 --passes 1
}

case "${1:-}" in
  pack) pack ;;
  pack-cell) pack_cell ;;
  cell) cell ;;
  torch) torch_stage ;;
  export) export_stage ;;
  stash) stash ;;
  bench) bench ;;
  bench-served) bench_served ;;
  serve-ab) serve_ab ;;
  other-devices) other_devices ;;
  export-served) export_served ;;
  threads) threads ;;
  pca-speed) pca_speed ;;
  *) echo "usage: $0 pack|pack-cell|cell|torch|export|export-served|stash|bench|bench-served|serve-ab|threads|pca-speed|other-devices" >&2; exit 2 ;;
esac
