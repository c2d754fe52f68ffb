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
python3 - "$YCBV" "$HOPE" "$OUT" <<'PY'
import json, os, sys
ycbv, hope, out = (os.path.realpath(p) for p in sys.argv[1:])
models = os.path.join(out, "models")
os.makedirs(models, exist_ok=True)
def link(src, dst):
    if not os.path.lexists(dst):
        os.symlink(src, dst)
info = json.load(open(os.path.join(ycbv, "models", "models_info.json")))
ycb_ids = sorted(int(k) for k in info)
hope_info = json.load(open(os.path.join(hope, "models", "models_info.json")))
hope_ids = []
for k, v in sorted(hope_info.items(), key=lambda kv: int(kv[0])):
    ply = os.path.join(hope, "models", f"obj_{int(k):06d}.ply")
    if not os.path.exists(ply):
        continue
    new = 100 + int(k)
    link(ply, os.path.join(models, f"obj_{new:06d}.ply"))
    png = ply[:-4] + ".png"
    if os.path.exists(png):
        link(png, os.path.join(models, os.path.basename(png)))
    info[str(new)] = v
    hope_ids.append(new)
for i in ycb_ids:
    link(os.path.join(ycbv, "models", f"obj_{i:06d}.ply"), os.path.join(models, f"obj_{i:06d}.ply"))
json.dump(info, open(os.path.join(models, "models_info.json"), "w"))
frames = sorted({(t["scene_id"], t["im_id"]) for t in json.load(open(os.path.join(ycbv, "test_targets_bop19.json")))})
truth = {}
def present(scene, im):
    if scene not in truth:
        truth[scene] = json.load(open(os.path.join(ycbv, "test", f"{scene:06d}", "scene_gt.json")))
    return [g["obj_id"] for g in truth[scene][str(im)]]
searched = {"onboard": (ycb_ids + hope_ids, frames[:1]), "n1": (None, frames), "n8": (ycb_ids + hope_ids[:1], frames), f"n{len(ycb_ids) + len(hope_ids)}": (ycb_ids + hope_ids, frames)}
for name, (objs, fr) in searched.items():
    view = os.path.join(out, name)
    os.makedirs(view, exist_ok=True)
    link(os.path.join(ycbv, "test"), os.path.join(view, "test"))
    link(models, os.path.join(view, "models"))
    targets = [{"scene_id": s, "im_id": i, "obj_id": o, "inst_count": 1} for s, i in fr for o in (objs if objs is not None else present(s, i)[:1])]
    json.dump(targets, open(os.path.join(view, "test_targets_bop19.json"), "w"))
PY
STORE="dir://$OUT/objects"
# Onboarding happens on an object's first use; a first pass keeps it out of the timed ones.
"$B2TF" bop run --dataset "$OUT/onboard" --out "$OUT/onboard.csv" --store "$STORE" --depth >"$OUT/onboard.log" 2>&1
for view in "$OUT"/n*; do
  name=$(basename "$view")
  rm -f "$OUT/$name.csv"
  start=$(date +%s.%N)
  "$B2TF" bop run --dataset "$view" --out "$OUT/$name.csv" --store "$STORE" --depth >"$OUT/$name.log" 2>&1
  seconds=$(echo "$(date +%s.%N) - $start" | bc)
  python3 - "$OUT/$name.csv" "$YCBV" "$name" "$seconds" <<'PY'
import csv, json, os, sys
path, ycbv, name, seconds = sys.argv[1:]
rows = list(csv.DictReader(open(path)))
truth = {}
def present(scene, im):
    if scene not in truth:
        truth[scene] = json.load(open(os.path.join(ycbv, "test", f"{int(scene):06d}", "scene_gt.json")))
    return {g["obj_id"] for g in truth[scene][str(int(im))]}
false = sum(int(r["obj_id"]) not in present(r["scene_id"], r["im_id"]) for r in rows)
targets = json.load(open(os.path.join(os.path.dirname(path), name, "test_targets_bop19.json")))
frames = len({(t["scene_id"], t["im_id"]) for t in targets})
per_frame = len(targets) // max(1, frames)
print(f"{name}: {per_frame} objects searched per frame, {float(seconds) / max(1, frames):.2f} s per frame ({float(seconds):.1f} s for {frames} frames, loading the objects included), {len(rows)} poses answered, {false} of them of objects not in their frame")
PY
done
