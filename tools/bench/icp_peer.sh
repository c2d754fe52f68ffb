#!/usr/bin/env bash
# The depth fit against a trusted peer: `b2tf bench depth-fit` dumps generated cases (the
# sensor model's depth, a start pose off the truth, the model points its render shows) and
# tools/bench/icp_peer.py fits the same points with Open3D's point-to-plane ICP.
#
#   tools/bench/icp_peer.sh [OUT] [-- extra `bench depth-fit` flags, e.g. --depth-mm 50]
#
# Installs Open3D (PyPI, ~400 MB) into .deps/open3d-venv the first time. A benchmark, not a
# test: about a minute on 2 cores with a release build (B2TF_BIN, default
# target/release/b2tf).
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT="${1:-out/depth-fit-cases}"
shift $(( $# < 1 ? $# : 1 ))
[ "${1:-}" = "--" ] && shift
B2TF="${B2TF_BIN:-target/release/b2tf}"
VENV=.deps/open3d-venv
if ! "$VENV/bin/python" -c "import open3d" >/dev/null 2>&1; then
  python3 -m venv "$VENV"
  "$VENV/bin/python" -m pip install --quiet open3d==0.20.0
fi
rm -rf "$OUT"
"$B2TF" bench depth-fit --dump "$OUT" "$@"
echo
"$VENV/bin/python" tools/bench/icp_peer.py "$OUT"
