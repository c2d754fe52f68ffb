#!/bin/sh
# The runtime stages' one RUN (CPU and GPU alike): the given Debian/Ubuntu packages without
# their recommendations, apt's lists and caches removed in the same layer, and the
# unprivileged user b2tf (uid/gid 10001) owning /data, the object store's volume.
set -eu
apt-get update
DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends "$@"
apt-get clean
rm -rf /var/lib/apt/lists/* /var/cache/apt/* /var/log/apt /var/log/dpkg.log
groupadd --gid 10001 b2tf
useradd --uid 10001 --gid b2tf --home-dir /data --no-create-home --shell /usr/sbin/nologin b2tf
install -d -o b2tf -g b2tf -m 0750 /data
