#!/usr/bin/env bash
# Every test: unit and integration tests (renderer on lavapipe, onboarding, loaders, CLI,
# the object stores, S3 against a real s3s-fs on loopback, the service over loopback:
# HTTP, gRPC, TLS), formatting (scripts/fmt.sh), clippy's lints, the OpenAPI document's validity, cargo-deny
# (scripts/deny.sh), the Python client's suite, the web console in a headless browser, the
# short overload and crash tests, and the container checks.
set -euo pipefail
cd "$(dirname "$0")/.."
# Each step's start, with the seconds since the script began: where CI's time goes.
step() { echo "== test.sh +${SECONDS}s ($(date +%T)): $*"; }
step setup
bash scripts/setup.sh
source scripts/env.sh
step formatting and import circles
# Formatting as written down (rustfmt.toml, ruff.toml): a file not formatted fails here.
bash scripts/fmt.sh --check
# No import circles between the crate's files (tools/import_circles.py names any).
python3 tools/import_circles.py
step OpenAPI and tool self-tests
# The OpenAPI validator (PyPI; setup.sh installed pip); Debian's Python may refuse
# system-wide installs.
python3 -c "import openapi_spec_validator" 2>/dev/null \
  || python3 -m pip install --quiet openapi-spec-validator 2>/dev/null \
  || python3 -m pip install --quiet --break-system-packages openapi-spec-validator
python3 tools/validate_openapi.py src/service/openapi.json
python3 tools/compare_runs.py --self-test
python3 tools/miss_classes.py --self-test
python3 tools/import_circles.py --self-test
python3 tools/bench/frame_time.py --self-test
step cargo-deny
# Licences, bans, sources (and advisories when GitHub answers): installs cargo-deny once.
bash scripts/deny.sh
step s3s-fs
# The S3 store's tests run against a real S3 server on loopback; installed, it must run.
bash scripts/install-s3s-fs.sh
export B2TF_S3S_FS="$PWD/.deps/s3s-fs/bin/s3s-fs" B2TF_REQUIRE_S3=1
# setup.sh installed lavapipe, so a missing adapter is a failure here, not a skip.
export B2TF_REQUIRE_GPU=1
# setup.sh installed ONNX Runtime: the ONNX backbone's tests run, they do not skip.
: "${B2TF_ORT_LIB:?scripts/env.sh found no ONNX Runtime library in .deps/python}"
step cargo test
cargo test --all-targets
step doc commands
# The commands the README and docs show name existing subcommands, flags and scripts.
python3 tools/check_doc_commands.py target/debug/b2tf
step clippy
# Lints as errors (where the toolchain has clippy; it needs no network once installed).
if cargo clippy --version >/dev/null 2>&1; then
  cargo clippy --all-targets --quiet -- -D warnings
else
  echo "clippy is not installed with this toolchain: lints SKIPPED"
fi
step Python client
bash clients/python/scripts/test.sh
step console
# The web console in headless Chromium (Debian's, installed when absent) against a real
# server with API keys: onboard, estimate from a drawn box and a painted mask, detect,
# scopes, delete (console/test; about 1 minute; screenshots in out/console-test).
B2TF_BIN="${B2TF_BIN:-target/debug/b2tf}" bash console/test/run.sh
step overload and crash
# Overload and crash safety, short modes (docs/reliability.md; ~1.5 min together): the
# server cargo test just built, Python from the client's venv that the step above made.
B2TF_BIN="${B2TF_BIN:-target/debug/b2tf}" tools/reliability/python.sh tools/loadtest.py --short
B2TF_BIN="${B2TF_BIN:-target/debug/b2tf}" tools/reliability/python.sh tools/crash_test.py --short
step containers
bash deploy/test.sh
step done
