#!/usr/bin/env bash
# Installs the S3 server the `s3://` store's tests run against: s3s-fs from crates.io (an
# S3 API over a local folder), into .deps/s3s-fs inside the checkout. Tests only; about
# 1.5 minutes once on 2 cores with the profile below. Idempotent.
set -euo pipefail
cd "$(dirname "$0")/.."
S3S_FS_VERSION=0.14.1
root=.deps/s3s-fs
if [ ! -f "$root/s3s-fs-$S3S_FS_VERSION.installed" ] || [ ! -x "$root/bin/s3s-fs" ]; then
  echo "installing s3s-fs $S3S_FS_VERSION into $root (the S3 store's test server)"
  CARGO_PROFILE_RELEASE_LTO=off CARGO_PROFILE_RELEASE_CODEGEN_UNITS=16 \
    cargo install --quiet --locked s3s-fs --version "$S3S_FS_VERSION" --features binary --root "$root"
  touch "$root/s3s-fs-$S3S_FS_VERSION.installed"
fi
