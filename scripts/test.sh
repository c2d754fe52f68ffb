#!/usr/bin/env bash
# Every test: unit and integration tests (renderer on lavapipe, onboarding, loaders, CLI,
# the service over loopback: HTTP, gRPC, TLS) and the OpenAPI document's validity.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
source scripts/env.sh
# The OpenAPI validator (PyPI; setup.sh installed pip); Debian's Python may refuse
# system-wide installs.
python3 -c "import openapi_spec_validator" 2>/dev/null \
  || python3 -m pip install --quiet openapi-spec-validator 2>/dev/null \
  || python3 -m pip install --quiet --break-system-packages openapi-spec-validator
python3 tools/validate_openapi.py src/service/openapi.json
# setup.sh installed lavapipe, so a missing adapter is a failure here, not a skip.
export B2TF_REQUIRE_GPU=1
# setup.sh installed ONNX Runtime: the ONNX backbone's tests run, they do not skip.
: "${B2TF_ORT_LIB:?scripts/env.sh found no ONNX Runtime library in .deps/python}"
cargo test --all-targets
bash clients/python/scripts/test.sh
bash deploy/test.sh
