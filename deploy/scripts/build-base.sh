#!/usr/bin/env bash
# Makes the Dockerfile's base image locally from Debian's packages, for machines that can
# reach Debian's mirror but no container registry (CI): mmdebstrap builds a minimal
# bookworm (variant minbase, documentation and locales left out as in debian:*-slim; /usr
# merged by mmdebstrap's hook rather than the usrmerge package, which would pull in perl) and
# buildah stores it under the exact name the Dockerfile's FROM uses, so the same
# Dockerfile builds here and, pulling the real image, with docker elsewhere.
# Idempotent: does nothing when the image exists (FORCE=1 rebuilds).
set -euo pipefail
name="${BASE_IMAGE:-docker.io/library/debian:bookworm-slim}"
mirror="${DEBIAN_MIRROR:-http://deb.debian.org/debian}"
if [ -z "${FORCE:-}" ] && buildah inspect --type image "$name" >/dev/null 2>&1; then
  echo "base image $name exists"; exit 0
fi
work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
# The image's own apt sources: the plain mirror and security updates, as the official image has.
mmdebstrap --variant=minbase --quiet --hook-dir=/usr/share/mmdebstrap/hooks/merged-usr \
  --dpkgopt='path-exclude=/usr/share/man/*' --dpkgopt='path-exclude=/usr/share/doc/*' \
  --dpkgopt='path-include=/usr/share/doc/*/copyright' --dpkgopt='path-exclude=/usr/share/locale/*' \
  --dpkgopt='path-exclude=/usr/share/info/*' \
  --customize-hook='rm -rf "$1"/var/lib/apt/lists/* "$1"/var/cache/apt/*.bin "$1"/var/log/*.log' \
  bookworm "$work/rootfs.tar" \
  "deb $mirror bookworm main" "deb $mirror bookworm-updates main" \
  "deb ${DEBIAN_SECURITY_MIRROR:-http://deb.debian.org/debian-security} bookworm-security main" \
  >"$work/mmdebstrap.log" 2>&1 || { cat "$work/mmdebstrap.log" >&2; exit 1; }
ctr="$(buildah from scratch)"
buildah add --quiet "$ctr" "$work/rootfs.tar" / >/dev/null
buildah config --cmd '["bash"]' --env PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin "$ctr"
buildah commit --quiet --rm "$ctr" "$name" >/dev/null
echo "base image $name: $(buildah inspect --type image --format '{{.FromImageID}}' "$name" | cut -c1-12)"
