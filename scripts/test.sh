#!/usr/bin/env bash
# Every test: unit and integration tests (renderer on lavapipe, onboarding, loaders, CLI).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
source scripts/env.sh
cargo test --all-targets
