#!/usr/bin/env bash
# Supply-chain checks with cargo-deny (configuration: deny.toml): licences (an allow-list),
# bans (several versions of a crate: warned), sources (crates.io only). Advisories need the
# RustSec database, which lives on GitHub: checked when GitHub answers, or always with
# B2TF_DENY_ADVISORIES=1 (then an unreachable database fails); B2TF_DENY_ADVISORIES=0 skips.
# Installs cargo-deny from crates.io when absent: 3 to 4 minutes on 2 shared cores with the
# profile below, against 8.5 with the crate's own (fat LTO, one codegen unit), measured.
set -euo pipefail
cd "$(dirname "$0")/.."
CARGO_DENY_VERSION="${CARGO_DENY_VERSION:-0.20.2}"
if ! command -v cargo-deny >/dev/null 2>&1; then
  echo "deny.sh: installing cargo-deny $CARGO_DENY_VERSION from crates.io"
  CARGO_PROFILE_RELEASE_LTO=off CARGO_PROFILE_RELEASE_CODEGEN_UNITS=16 \
    cargo install --quiet --locked cargo-deny --version "$CARGO_DENY_VERSION"
fi
# Errors in full, warnings (the duplicate versions) as counts: `cargo deny check bans`
# lists them.
cargo deny --log-level error check --show-stats licenses bans sources

reachable() {
  timeout 15 git ls-remote --exit-code https://github.com/rustsec/advisory-db HEAD >/dev/null 2>&1 \
    || timeout 15 curl -sfI https://github.com/rustsec/advisory-db >/dev/null 2>&1
}
case "${B2TF_DENY_ADVISORIES:-auto}" in
  0) echo "deny.sh: advisories SKIPPED (B2TF_DENY_ADVISORIES=0)" ;;
  1) cargo deny check --hide-inclusion-graph advisories ;;
  *)
    if reachable; then
      cargo deny check --hide-inclusion-graph advisories
    else
      echo "deny.sh: advisories SKIPPED: the RustSec database (github.com/rustsec/advisory-db) cannot be reached from here; B2TF_DENY_ADVISORIES=1 makes that a failure"
    fi
    ;;
esac
