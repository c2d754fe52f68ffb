#!/usr/bin/env bash
# Boxes against true masks on real frames (RGB only): `b2tf bop run` on a BOP dataset
# once with its mask detections and once with its box-only detections, each scored by
# `b2tf bop eval` (AR per object). Default: ../shared/data/ycbv-rgbd (10 real YCB-V frames,
# 35 instances, detections.json / detections_box.json beside them).
#
#   tools/bench/real_boxes.sh [DATASET] [OUT] [-- extra `bop run` flags for the box run]
#
# BOTH="--depth" adds flags to both runs (RGB-D: each image's depth/ with its depth_scale).
# JITTER_SEEDS="1 2 3 4 5" runs the boxes again with each side moved by up to JITTER (default
# 0.02) of the box's side, one seeded draw per seed (tools/bench/jitter_boxes.py), and prints
# each run's AR and their mean with the exact boxes': one run on these 35 boxes moves by
# several hundredths with a pixel of the boxes (docs/estimation.md, "How much one box run says").
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
[ -n "${JITTER_SEEDS:-}" ] || exit 0
ars=("$(awk -F'|' '/^\| all /{print $4}' "$OUT/boxes-eval.md")")
for seed in $JITTER_SEEDS; do
  python3 tools/bench/jitter_boxes.py "$DS/detections_box.json" "$OUT/boxes-jitter-$seed.json" --seed "$seed" --jitter "${JITTER:-0.02}"
  rm -f "$OUT/boxes-jitter-$seed.csv"
  start=$(date +%s.%N)
  "$B2TF" bop run --dataset "$DS" --detections "$OUT/boxes-jitter-$seed.json" --out "$OUT/boxes-jitter-$seed.csv" --store "$STORE" ${BOTH:-} "$@" >"$OUT/boxes-jitter-$seed.log" 2>&1
  secs=$(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }')
  ar=$("$B2TF" bop eval --dataset "$DS" --results "$OUT/boxes-jitter-$seed.csv" | tee "$OUT/boxes-jitter-$seed-eval.md" | awk -F'|' '/^\| all /{gsub(/ /, "", $4); print $4}')
  echo "boxes jittered (seed $seed): AR $ar, bop run $secs s"
  ars+=("$ar")
done
printf '%s\n' "${ars[@]}" | awk '{ s += $1; n++ } END { printf "boxes: mean AR %.3f over %d runs (the exact boxes and %d jitters)\n", s / n, n, n - 1 }'
