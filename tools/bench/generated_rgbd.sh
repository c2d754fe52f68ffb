#!/usr/bin/env bash
# Generated BOP scenes with a depth camera's depth, scored in BOP AR: the HOPE meshes with
# and without their textures, 2–6 objects an image with occluders, some objects standing in
# the scenes as distractors nobody searches for; each estimated from the true visible masks
# and from their boxes, with and without depth (`bop synth`, `bop run [--depth]`,
# `bop eval`). Prints each run's AR table (per object, with half-turns) and a summary
# (OUT/summary.md), with the AR up to the symmetries found in each mesh (`bop eval
# --mesh-symmetries`: on bare meshes, what is left once turns the shape cannot tell are forgiven).
# Runs already done are kept (OUT/*.csv.done): delete them to rerun.
#
#   tools/bench/generated_rgbd.sh [MODELS] [OUT]
#
# MODELS: a BOP models folder (default ../shared/data/hope/models). TARGETS (default
# 1,2,3,4,8,11) names the searched objects; IMAGES (default 12), SEED (default 1).
# BACKGROUNDS (a BOP dataset of real frames, e.g. ../shared/data/empty-rgbd) draws every
# image over one of its photos, its measured depth behind the objects (`bop synth
# --backgrounds`): real clutter where procedural clutter flatters. MESHES (default
# "textured untextured") and DEPTHS (default "rgb rgbd") choose the runs. CLUSTERED=1
# places the objects beside each other (`bop synth --clustered`), as on a bench.
# Heavy (about 25 minutes on 2 cores with a release build the first time, onboarding
# included; the objects stay in OUT/objects-*): a benchmark, not a test. B2TF_BIN names
# the binary (default target/release/b2tf).
set -euo pipefail
cd "$(dirname "$0")/../.."
MODELS="${1:-../shared/data/hope/models}"
OUT="${2:-out/generated-rgbd}"
TARGETS="${TARGETS:-1,2,3,4,8,11}"
IMAGES="${IMAGES:-12}"
SEED="${SEED:-1}"
B2TF="${B2TF_BIN:-target/release/b2tf}"
MESHES="${MESHES:-textured untextured}"
DEPTHS="${DEPTHS:-rgb rgbd}"
synth_extra=()
[ -n "${BACKGROUNDS:-}" ] && synth_extra+=(--backgrounds "$BACKGROUNDS")
[ -n "${CLUSTERED:-}" ] && synth_extra+=(--clustered)
mkdir -p "$OUT"
summary="$OUT/summary.md"
echo "| meshes | detections | depth | AR | AR_VSD | AR_MSSD | AR_MSPD | MSSD < 0.1·d | half-turns | AR up to the mesh's symmetries | s per instance |" >"$summary"
echo "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|" >>"$summary"
for tex in $MESHES; do
  ds="$OUT/ds-$tex"
  flags=()
  [ "$tex" = untextured ] && flags+=(--untextured)
  if [ ! -f "$ds/test_targets_bop19.json" ]; then
    "$B2TF" bop synth --models "$MODELS" --out "$ds" --images "$IMAGES" --objects-per-image 2,6 --targets "$TARGETS" \
      --seed "$SEED" --no-degraded --no-distractors "${flags[@]}" "${synth_extra[@]}"
  fi
  store="dir://$OUT/objects-$tex"
  # Onboarding happens on an object's first use; a first pass keeps it out of the timed runs.
  if [ ! -d "$OUT/objects-$tex" ]; then
    "$B2TF" bop run --dataset "$ds" --detections "$ds/detections_synth.json" --out "$OUT/$tex-onboard.csv" --store "$store" >"$OUT/$tex-onboard.log" 2>&1
  fi
  for kind in masks boxes; do
    det="$ds/detections_synth.json"
    [ "$kind" = boxes ] && det="$ds/detections_box.json"
    for depth in $DEPTHS; do
      extra=()
      [ "$depth" = rgbd ] && extra+=(--depth)
      csv="$OUT/$tex-$kind-$depth.csv"
      if [ ! -f "$csv.done" ]; then
        rm -f "$csv"
        "$B2TF" bop run --dataset "$ds" --detections "$det" --out "$csv" --store "$store" "${extra[@]}" >"$OUT/$tex-$kind-$depth.log" 2>&1
        touch "$csv.done"
      fi
      echo "== $tex, $kind, $depth"
      "$B2TF" bop eval --dataset "$ds" --results "$csv" | tee "$OUT/$tex-$kind-$depth-eval.md"
      "$B2TF" bop eval --dataset "$ds" --results "$csv" --json >"$OUT/$tex-$kind-$depth-eval.json"
      # Not BOP: up to the symmetries found in each mesh (a bare box's half-turns forgiven).
      "$B2TF" bop eval --dataset "$ds" --results "$csv" --json --mesh-symmetries >"$OUT/$tex-$kind-$depth-eval-mesh.json"
      python3 - "$OUT/$tex-$kind-$depth-eval.json" "$csv" "$tex" "$kind" "$depth" "$OUT/$tex-$kind-$depth-eval-mesh.json" >>"$summary" <<'EOF'
import csv, json, sys
r = json.load(open(sys.argv[1]))
shape = json.load(open(sys.argv[6]))
per_image, rows = {}, 0
for row in csv.DictReader(open(sys.argv[2])):
    per_image[(row["scene_id"], row["im_id"])] = float(row["time"])
    rows += 1
secs = sum(per_image.values()) / max(rows, 1)
turned = sum(o.get("half_turns", 0) for o in r["per_object"].values())
print(f"| {sys.argv[3]} | {sys.argv[4]} | {sys.argv[5]} | {r['ar']:.3f} | {r['ar_vsd']:.3f} | {r['ar_mssd']:.3f} | {r['ar_mspd']:.3f} | {r['recalls']['mssd'][1]:.3f} | {turned} of {r['targets']} | {shape['ar']:.3f} | {secs:.2f} |")
EOF
    done
  done
done
echo
cat "$summary"
