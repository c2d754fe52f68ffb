#!/usr/bin/env bash
# Every test: unit and integration tests (renderer on lavapipe, onboarding, loaders, CLI,
# the service over loopback: HTTP, gRPC, TLS) and the OpenAPI document's validity.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
source scripts/env.sh
# The OpenAPI validator (PyPI); Debian's Python may lack pip or refuse system-wide installs.
if ! python3 -m pip --version >/dev/null 2>&1; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq python3-pip >/dev/null
fi
python3 -c "import openapi_spec_validator" 2>/dev/null \
  || python3 -m pip install --quiet openapi-spec-validator 2>/dev/null \
  || python3 -m pip install --quiet --break-system-packages openapi-spec-validator
python3 tools/validate_openapi.py src/service/openapi.json
# setup.sh installed lavapipe, so a missing adapter is a failure here, not a skip.
export B2TF_REQUIRE_GPU=1
cargo test --all-targets
