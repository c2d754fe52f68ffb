#!/usr/bin/env bash
# The main job on the embedded defaults: `b2tf demo` generates a textured object, onboards
# it (1944 templates, embedded backbone, lavapipe), renders a photo-like scene of it,
# estimates its pose (retrieval, matching, RANSAC-PnP, RRC, selection), prints the errors
# against the truth and writes the overlay. Outputs go to out/demo/ (git-ignored).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
source scripts/env.sh
cargo build --release --quiet
target/release/b2tf demo --out out/demo "$@"
