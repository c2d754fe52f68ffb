#!/usr/bin/env bash
# Tests tools/export_backbone.py on small randomly initialised DINOv3 and DINOv2-with-
# registers models built from transformers configs (no weights needed): each export is
# checked against PyTorch by the script itself (fp32 and fp16), then loaded and run by
# b2tf's ONNX backbone on a generated scene. Not part of CI: torch's Linux wheels pull
# CUDA packages, 5.6 GB installed (measured 2026-11-23: 1 min 52 s to install here),
# so this installs them into .deps/torch only when run.
#   tools/test_export.sh [OUT_DIR]
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
source scripts/env.sh
torch_deps="$PWD/.deps/torch"
if [ ! -f "$torch_deps/installed" ]; then
  python3 -m pip install --quiet --disable-pip-version-check --target "$torch_deps" "torch==2.15.0" "transformers>=4.56,<6"
  touch "$torch_deps/installed"
fi
out="${1:-out/export-test}"
mkdir -p "$out"
cargo build --release --quiet
for spec in "dinov3-tiny:" "dinov3-tiny:--fp16" "dinov3-tiny:--fused-attention" "dinov3-tiny:--fp16 --fused-attention" "dinov2reg-tiny:" "dinov2reg-tiny:--fused-attention"; do
  kind="${spec%%:*}"; flags="${spec#*:}"
  name="$kind"; [[ $flags == *--fp16* ]] && name+="-fp16"; [[ $flags == *--fused-attention* ]] && name+="-mha"
  PYTHONPATH="$torch_deps:$PYTHONPATH" python3 tools/export_backbone.py --random-init "$kind" $flags --out "$out/$name.onnx" 2>&1 | grep -E "tokens \[|wrote"
  target/release/b2tf bench estimate --backbone "onnx:$out/$name.onnx" --images 1 --store "dir://$out/models" | grep -E "^\| with RRC"
done
# The parity check refuses: fp16 cannot meet a 1e-7 tolerance, so nothing may be written.
rm -f "$out/refused.onnx" "$out/refused.json"
if PYTHONPATH="$torch_deps:$PYTHONPATH" python3 tools/export_backbone.py --random-init dinov3-tiny --fp16 --tolerance 1e-7 --out "$out/refused.onnx" 2>"$out/refused.err"; then
  echo "export with an unreachable tolerance succeeded" >&2; exit 1
fi
grep -q "disagrees with PyTorch" "$out/refused.err" || { cat "$out/refused.err" >&2; exit 1; }
[ ! -e "$out/refused.onnx" ] && [ ! -e "$out/refused.json" ] || { echo "a refused export left files behind" >&2; exit 1; }
echo "export test passed: $out"
