#!/usr/bin/env bash
# Builds deploy/Dockerfile with buildah (no docker daemon, no registry: the FROM images must
# exist locally, see build-base.sh).
#   buildah-build.sh CONTEXT TAG [FLAVOR=cpu|gpu] [BINARY_FROM=build|prebuilt] [buildah bud args…]
# CONTEXT holds the repository's files (the repository root for a full build; deploy/test.sh
# makes a small one with prebuilt/b2tf). Behind a TLS-intercepting proxy the host's CA
# bundle ($SSL_CERT_FILE) goes in as the build secret build_ca: mounted only for the steps
# that download, never in a layer.
set -euo pipefail
context="$1" tag="$2" flavor="${3:-cpu}" binary_from="${4:-build}"
shift $(( $# < 4 ? $# : 4 ))
extra=()
if [ -n "${SSL_CERT_FILE:-}" ] && [ -f "$SSL_CERT_FILE" ]; then
  extra+=(--secret "id=build_ca,src=$SSL_CERT_FILE")
fi
# chroot isolation: works unprivileged in CI containers; it shares the host's network.
# FLAVOR and BINARY_FROM are passed even at their defaults: buildah 1.28 keeps the stages
# an argument-named FROM needs only for arguments given on the command line.
# buildah 1.28 leaves the working container of the one-line alias stage (FROM
# ${BINARY_FROM} AS binary) behind: remove the containers this build created.
before="$(buildah containers --quiet --notruncate | sort)"
leftovers() { comm -13 <(echo "$before") <(buildah containers --quiet --notruncate | sort); }
trap 'leftovers | xargs -r buildah rm >/dev/null' EXIT
# docker format: OCI image configs have no HEALTHCHECK (buildah would drop it).
buildah bud --isolation chroot --pull=never --layers --format docker \
  --build-arg FLAVOR="$flavor" --build-arg BINARY_FROM="$binary_from" \
  --build-arg REVISION="$(git -C "$(dirname "$0")" rev-parse --short HEAD 2>/dev/null || echo unknown)" \
  "${extra[@]}" "$@" -f "$context/deploy/Dockerfile" -t "$tag" "$context"
