#!/usr/bin/env bash
# Builds the Python client's sdist and wheel into clients/python/dist/ (or the folder
# given as $1). `python -m build` makes the sdist first and the wheel from it, so the
# wheel proves the sdist is complete (it carries proto/; setup.py generates the stubs).
set -euo pipefail
unset PYTHONPATH  # scripts/env.sh's .deps/python would leak into the isolated build
cd "$(dirname "$0")/.."
REPO="$(cd ../.. && pwd)"
PY="${PYTHON:-$REPO/.deps/pyclient-venv/bin/python}"
[ -x "$PY" ] || PY=python3
OUT="${1:-dist}"
rm -rf build "$OUT"/b2tfpose-*
"$PY" -m build --outdir "$OUT" . >"${TMPDIR:-/tmp}/b2tfpose-build.log" 2>&1 \
  || { cat "${TMPDIR:-/tmp}/b2tfpose-build.log"; exit 1; }
ls "$OUT"
