#!/usr/bin/env bash
# The Python client's tests against a real `b2tf serve` ($B2TF_BIN, else target/debug/b2tf,
# else target/release/b2tf: build it first, e.g. with `cargo test` or `cargo build`).
# Idempotent and quick on a second run: the venv and its pinned packages are kept in
# .deps/pyclient-venv and reinstalled only when scripts/requirements-test.txt changes.
# Builds the sdist and wheel (scripts/build.sh -> dist/), installs the package, then runs
# pytest, which also installs the wheel into a fresh venv and runs mypy --strict on the
# examples.
set -euo pipefail
# scripts/env.sh (sourced by the repository's scripts/test.sh before this, and below) puts
# .deps/python (the Rust tools' numpy, protobuf, onnxruntime) on PYTHONPATH, which would
# shadow the venv's pinned packages and the build's own.
unset PYTHONPATH
cd "$(dirname "$0")/.."
REPO="$(cd ../.. && pwd)"
VENV="$REPO/.deps/pyclient-venv"
REQ=scripts/requirements-test.txt

# Debian's Python may come without venv/ensurepip (the tests also make a fresh venv).
if ! python3 -c "import ensurepip, venv" >/dev/null 2>&1; then
  SUDO=""; [ "$(id -u)" = 0 ] || SUDO=sudo
  $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq python3-venv >/dev/null
fi
[ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
want="$(sha256sum "$REQ" | cut -d' ' -f1)"
if [ "$(cat "$VENV/.requirements-test.sha256" 2>/dev/null)" != "$want" ]; then
  "$VENV/bin/python" -m pip install --quiet --upgrade pip
  "$VENV/bin/python" -m pip install --quiet -r "$REQ"
  echo "$want" >"$VENV/.requirements-test.sha256"
fi

PYTHON="$VENV/bin/python" bash scripts/build.sh dist
# The package under test, from this source tree (its stubs generated from ../../proto).
"$VENV/bin/python" -m pip install --quiet --no-deps --force-reinstall .
rm -rf build

source "$REPO/scripts/env.sh"
unset PYTHONPATH
export B2TFPOSE_DIST="$PWD/dist"
"$VENV/bin/python" -m pytest -q -p no:cacheprovider tests "$@"
