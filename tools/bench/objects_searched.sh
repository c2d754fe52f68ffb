#!/usr/bin/env bash
# Time per frame against the number of objects searched, with depth and no detections
# given: the real YCB-V frames searched for 1 object (the first one in each frame), for 8
# (the 7 YCB-V objects and one HOPE object) and for 17 (the 7 and the 10 HOPE meshes, none
# of which is in the frames). Each run is `b2tf bop run --depth` without --detections; it
# prints the seconds per frame (the run's wall-clock time over its frames), the poses
# answered, and how many of them are of objects not in their frame (false answers).
#
#   tools/bench/objects_searched.sh [YCBV] [HOPE] [OUT]
#
# Defaults: ../shared/data/ycbv-rgbd, ../shared/data/hope (its models/ folder),
# out/many-objects. Heavy (about 10 minutes on 2 cores with a release build, 8 more the
# first time, to onboard the 17 objects into OUT/objects): a benchmark, not a test. B2TF_BIN
# names the binary (default target/release/b2tf).
set -euo pipefail
cd "$(dirname "$0")/../.."
YCBV="${1:-../shared/data/ycbv-rgbd}"
HOPE="${2:-../shared/data/hope}"
OUT="${3:-out/many-objects}"
B2TF="${B2TF_BIN:-target/release/b2tf}"
mkdir -p "$OUT"
# One models folder: the YCB-V meshes under their ids, the HOPE meshes as 101, 102, ...
# (their textures keep their names: no YCB-V mesh has one).
python3 tools/bench/objects_searched.py views "$YCBV" "$HOPE" "$OUT"
STORE="dir://$OUT/objects"
# Onboarding happens on an object's first use; a first pass keeps it out of the timed ones.
"$B2TF" bop run --dataset "$OUT/onboard" --out "$OUT/onboard.csv" --store "$STORE" --depth >"$OUT/onboard.log" 2>&1
# The views only (a rerun finds their CSVs and logs beside them).
for view in "$OUT"/n*/; do
  name=$(basename "$view")
  rm -f "$OUT/$name.csv"
  start=$(date +%s.%N)
  "$B2TF" bop run --dataset "$view" --out "$OUT/$name.csv" --store "$STORE" --depth >"$OUT/$name.log" 2>&1
  seconds=$(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }')
  python3 tools/bench/objects_searched.py report "$OUT/$name.csv" "$YCBV" "$name" "$seconds"
done
