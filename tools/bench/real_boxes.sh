#!/usr/bin/env bash
# Boxes against true masks on real frames (RGB only): `b2tf bop run` on a BOP dataset
# once with its mask detections and once with its box-only detections, each scored by
# `b2tf bop eval` (AR per object). Default: ../shared/data/ycbv-rgbd (10 real YCB-V frames,
# 35 instances, detections.json / detections_box.json beside them).
#
#   tools/bench/real_boxes.sh [DATASET] [OUT] [-- extra `bop run` flags for the box run]
#
# BOTH="--depth" adds flags to both runs (RGB-D: each image's depth/ with its depth_scale).
#
# Heavy (about 5 minutes on 2 cores with a release build, and 4 more the first time, to
# onboard the objects into OUT/objects): a benchmark, not a test. B2TF_BIN names the binary
# (default target/release/b2tf).
set -euo pipefail
cd "$(dirname "$0")/../.."
DS="${1:-../shared/data/ycbv-rgbd}"
OUT="${2:-out/real-boxes}"
shift $(( $# < 2 ? $# : 2 ))
[ "${1:-}" = "--" ] && shift
B2TF="${B2TF_BIN:-target/release/b2tf}"
mkdir -p "$OUT"
STORE="dir://$OUT/objects"
# Onboarding happens on an object's first use; a first pass keeps it out of the timed ones.
if [ ! -d "$OUT/objects" ]; then
  "$B2TF" bop run --dataset "$DS" --detections "$DS/detections.json" --out "$OUT/onboard.csv" --store "$STORE" >"$OUT/onboard.log" 2>&1
fi
for kind in masks boxes; do
  det="$DS/detections.json"; extra=(${BOTH:-})
  if [ "$kind" = boxes ]; then det="$DS/detections_box.json"; extra+=("$@"); fi
  rm -f "$OUT/$kind.csv"
  start=$(date +%s.%N)
  "$B2TF" bop run --dataset "$DS" --detections "$det" --out "$OUT/$kind.csv" --store "$STORE" "${extra[@]}" >"$OUT/$kind.log" 2>&1
  echo "$kind: bop run $(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }') s"
  "$B2TF" bop eval --dataset "$DS" --results "$OUT/$kind.csv" | tee "$OUT/$kind-eval.md"
done
