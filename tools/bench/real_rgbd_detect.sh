#!/usr/bin/env bash
# The one-call path on real RGB-D frames, with no detections given: `b2tf bop run` finds
# each image's targets itself, with depth (`--depth`: the depth detector, docs/detection.md
# "With depth") and without (the colour-only detector), each scored by `b2tf bop eval`
# (AR per object, against the truth); then, on real frames holding none of the objects,
# every object searched in every frame with depth: each pose answered there is false.
#
#   tools/bench/real_rgbd_detect.sh [DATASET] [EMPTY] [OUT]
#
# Defaults: ../shared/data/ycbv-rgbd (10 real YCB-V frames, 35 instances),
# ../shared/data/empty-rgbd (10 real kitchen frames without them), out/real-rgbd-detect.
# Heavy (about 3 minutes on 2 cores with a release build, 4 more the first time, to
# onboard the objects into OUT/objects): a benchmark, not a test. B2TF_BIN names the
# binary (default target/release/b2tf).
set -euo pipefail
cd "$(dirname "$0")/../.."
DS="${1:-../shared/data/ycbv-rgbd}"
EMPTY="${2:-../shared/data/empty-rgbd}"
OUT="${3:-out/real-rgbd-detect}"
B2TF="${B2TF_BIN:-target/release/b2tf}"
mkdir -p "$OUT"
STORE="dir://$OUT/objects"
# Onboarding happens on an object's first use; a first pass keeps it out of the timed ones.
if [ ! -d "$OUT/objects" ]; then
  "$B2TF" bop run --dataset "$DS" --detections "$DS/detections.json" --out "$OUT/onboard.csv" --store "$STORE" >"$OUT/onboard.log" 2>&1
fi
for kind in depth colour; do
  extra=(); [ "$kind" = depth ] && extra=(--depth)
  rm -f "$OUT/$kind.csv"
  start=$(date +%s.%N)
  "$B2TF" bop run --dataset "$DS" --out "$OUT/$kind.csv" --store "$STORE" --detections-out "$OUT/$kind-detections.json" "${extra[@]}" >"$OUT/$kind.log" 2>&1
  echo "$kind: bop run $(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }') s; $(tail -1 "$OUT/$kind.log")"
  "$B2TF" bop eval --dataset "$DS" --results "$OUT/$kind.csv" | tee "$OUT/$kind-eval.md"
done
# The empty frames as a dataset whose every image asks for one instance of every object.
view="$OUT/empty-view"
rm -rf "$view"; mkdir -p "$view"
ln -s "$(realpath "$EMPTY/test")" "$view/test"
ln -s "$(realpath "$DS/models")" "$view/models"
python3 - "$EMPTY" "$DS" "$view/test_targets_bop19.json" <<'PY'
import json, os, sys
empty, ds, out = sys.argv[1:]
objs = sorted({t["obj_id"] for t in json.load(open(os.path.join(ds, "test_targets_bop19.json")))})
targets = []
for scene in sorted(os.listdir(os.path.join(empty, "test"))):
    for name in sorted(os.listdir(os.path.join(empty, "test", scene, "rgb"))):
        im = int(os.path.splitext(name)[0])
        targets += [{"scene_id": int(scene), "im_id": im, "obj_id": o, "inst_count": 1} for o in objs]
json.dump(targets, open(out, "w"))
print(f"empty frames: {len(targets)} searches ({len(objs)} objects per frame)")
PY
rm -f "$OUT/empty.csv"
start=$(date +%s.%N)
"$B2TF" bop run --dataset "$view" --out "$OUT/empty.csv" --store "$STORE" --depth >"$OUT/empty.log" 2>&1
answered=$(( $(wc -l <"$OUT/empty.csv") - 1 ))
searches=$(python3 -c "import json;print(len(json.load(open('$view/test_targets_bop19.json'))))")
echo "empty frames, depth: $answered poses answered over $searches searches ($(awk -v a="$answered" -v n="$searches" 'BEGIN { printf "%.3f", a / n }') per frame per object), $(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN { printf "%.1f", b - a }') s"
