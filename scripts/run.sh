#!/usr/bin/env bash
# The main job on the embedded defaults: generate the sample object, onboard it (1944
# templates, embedded backbone, lavapipe), and render it through a camera for a look.
# Outputs go to out/ (git-ignored).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
source scripts/env.sh
cargo build --release --quiet
B2TF=target/release/b2tf
mkdir -p out
$B2TF sample --out out/sample
$B2TF onboard --mesh out/sample/sample_box.obj --units m --id sample-box --out out/models --replace
cat > out/camera.json <<'JSON'
{"K": [[600.0, 0.0, 319.5], [0.0, 600.0, 239.5], [0.0, 0.0, 1.0]], "resolution": [480, 640]}
JSON
$B2TF render --mesh out/sample/sample_box.obj --units m --camera out/camera.json --out out/render \
  --pose "0.8660254,0,0.5, 0.25,0.8660254,-0.4330127, -0.4330127,0.5,0.75, 0.01,-0.02,0.45"
echo "done: object model in out/models/sample-box, render in out/render/"
