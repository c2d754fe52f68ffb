#!/usr/bin/env bash
# Runs a reliability tool (tools/loadtest.py, tools/crash_test.py) with a Python that has
# the b2tfpose client: the client's test venv .deps/pyclient-venv, which
# clients/python/scripts/test.sh makes (scripts/test.sh runs that just before these
# tools), else that venv made here with the client installed from this checkout (its
# grpcio, protobuf and numpy from PyPI). Usage: tools/reliability/python.sh TOOL.py ARGS
set -euo pipefail
REPO="$(cd "$(dirname "$0")/../.." && pwd)"
VENV="$REPO/.deps/pyclient-venv"
# scripts/env.sh puts .deps/python on PYTHONPATH, whose packages would shadow the venv's.
unset PYTHONPATH
if ! "$VENV/bin/python" -c "import b2tfpose" >/dev/null 2>&1; then
  if ! python3 -c "import ensurepip, venv" >/dev/null 2>&1; then
    SUDO=""; [ "$(id -u)" = 0 ] || SUDO=sudo
    $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq python3-venv >/dev/null
  fi
  [ -x "$VENV/bin/python" ] || python3 -m venv "$VENV"
  "$VENV/bin/python" -m pip install --quiet "$REPO/clients/python"
  rm -rf "$REPO/clients/python/build"
fi
exec "$VENV/bin/python" "$@"
