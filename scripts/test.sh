#!/usr/bin/env bash
# Every test: unit and integration tests (renderer on lavapipe, onboarding, loaders, CLI).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
source scripts/env.sh
# setup.sh installed lavapipe, so a missing adapter is a failure here, not a skip.
export B2TF_REQUIRE_GPU=1
cargo test --all-targets
