#!/usr/bin/env bash
# Formatting as written down: rustfmt.toml for the Rust crates, ruff.toml for the Python
# (ruff pinned, in .deps/ruff-venv). `scripts/fmt.sh` formats the tree; `--check` (the
# test script's) fails on any file that is not formatted, naming it.
set -euo pipefail
cd "$(dirname "$0")/.."
RUFF_VERSION=0.14.0
RUFF=.deps/ruff-venv/bin/ruff
if [ "$("$RUFF" --version 2>/dev/null)" != "ruff $RUFF_VERSION" ]; then
  python3 -m venv .deps/ruff-venv
  .deps/ruff-venv/bin/python -m pip install --quiet "ruff==$RUFF_VERSION"
fi
if [ "${1:-}" = --check ]; then
  cargo fmt --check
  git ls-files -z '*.py' | xargs -0 "$RUFF" format --check
else
  cargo fmt
  git ls-files -z '*.py' | xargs -0 "$RUFF" format
fi
