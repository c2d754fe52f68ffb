#!/usr/bin/env bash
# The image with a read-only root file system, only /tmp (tmpfs) and the store volume
# writable, as docker-compose.yml (read_only: true) and the Kubernetes manifests
# (readOnlyRootFilesystem) run it: ready (the warm-up renders and runs the backbone),
# answers, stops with exit status 0 on SIGTERM, and wrote nothing but the store.
#   readonly-root.sh IMAGE
# buildah cannot make a container's root read-only, so this script does what a runtime
# would, by hand: in a private mount namespace it bind-mounts the image's root read-only,
# adds /tmp, /data, /dev and /proc, and chroots to the image's user with the image's
# environment and entrypoint.
set -euo pipefail
image="$1"
if [ -z "${B2TF_IN_MOUNT_NS:-}" ]; then
  B2TF_IN_MOUNT_NS=1 exec unshare --mount --propagation private --fork bash "$0" "$@"
fi
port="${SMOKE_HTTP_PORT:-18080}"
ctr="$(buildah from --pull=never "$image")"
work="$(mktemp -d)"
data="$work/data" log="$work/server.log"
mkdir "$data"
trap 'buildah umount "$ctr" >/dev/null; buildah rm "$ctr" >/dev/null; rm -rf "$work"' EXIT
root="$(buildah mount "$ctr")"
inspect() { buildah inspect --type image --format "$1" "$image"; }
user="$(inspect '{{.Docker.Config.User}}')"
chown "$user" "$data"
mapfile -t env < <(inspect '{{range .Docker.Config.Env}}{{println .}}{{end}}' | grep .)
read -r -a entrypoint <<<"$(inspect '{{range .Docker.Config.Entrypoint}}{{.}} {{end}}')"
mount --bind "$root" "$root" && mount -o remount,bind,ro "$root"
mount -t tmpfs -o mode=1777 tmpfs "$root/tmp"
mount --bind "$data" "$root/data"
mount --rbind /dev "$root/dev"
mount -t proc proc "$root/proc"
touch "$root/usr/.probe" 2>/dev/null && { echo "root is writable" >&2; exit 1; }
chroot --userspec="$user" "$root" /usr/bin/env -i "${env[@]}" B2TF_HTTP_ADDR="127.0.0.1:$port" \
  B2TF_GRPC_ADDR=127.0.0.1:0 "${entrypoint[@]}" >"$log" 2>&1 &
server=$!
for _ in $(seq 1 600); do
  [ "$(curl -s -o /dev/null -w '%{http_code}' "http://127.0.0.1:$port/readyz")" = 200 ] && break
  kill -0 "$server" 2>/dev/null || break
  sleep 0.1
done
ok=0
curl -sf "http://127.0.0.1:$port/v1/objects" >/dev/null && ok=1
kill -TERM "$server"
rc=0; wait "$server" || rc=$?
[ "$ok" = 1 ] && [ "$rc" = 0 ] || { cat "$log" >&2; echo "read-only root: not ready or no clean stop (exit $rc)" >&2; exit 1; }
[ "$(ls -A "$data")" = objects ] || { echo "wrote beside the store: $(ls -A "$data")" >&2; exit 1; }
echo "read-only root file system (only /tmp and /data writable): ready, answered, SIGTERM exit 0"
