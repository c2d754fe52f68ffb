#!/usr/bin/env bash
# Runs an image the way a container engine would and uses it over loopback:
#   smoke.sh IMAGE
# 1. starts the image's ENTRYPOINT (read from the image) with the store volume at /data,
#    times start → /readyz 200, and runs the image's HEALTHCHECK command;
# 2. onboards the sample box (multipart, as in the README) and estimates its pose in a
#    rendered photo (both made by the image's own b2tf), checks the pose and /metrics
#    (and that the Grafana dashboard's queries name only metrics found there);
# 3. stops it with SIGTERM (exit 0, "stopped") and checks the store on the volume (owned by
#    the image's non-root user);
# 4. starts it again with the volume read-only (a Kubernetes replica): ready, lists and
#    estimates the object, cannot add one, stops cleanly.
# buildah's chroot isolation shares the host network: the server listens on host loopback.
set -euo pipefail
image="$1"
here="$(cd "$(dirname "$0")" && pwd)"
http_port="${SMOKE_HTTP_PORT:-18080}" grpc_port="${SMOKE_GRPC_PORT:-15051}"
base="http://127.0.0.1:$http_port"
work="$(mktemp -d)"
data="$work/data" files="$work/files"
mkdir -p "$data" "$files"
ctr="$(buildah from --pull=never "$image")"
# buildah run mounts the image's VOLUME /data over a -v for the same path (docker and
# Kubernetes do not): drop the declaration from this working container, not the image.
buildah config --volume /data- "$ctr"
uid="$(buildah inspect --type container --format '{{.OCIv1.Config.User}}' "$ctr")"
chown "$uid" "$data" "$files"
runner=""
cleanup() {
  [ -n "$runner" ] && kill -0 "$runner" 2>/dev/null && stop_server || true
  buildah rm "$ctr" >/dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT
read -r -a entrypoint <<<"$(buildah inspect --type container --format '{{range .OCIv1.Config.Entrypoint}}{{.}} {{end}}' "$ctr")"
env_args=(-e "B2TF_HTTP_ADDR=127.0.0.1:$http_port" -e "B2TF_GRPC_ADDR=127.0.0.1:$grpc_port")
since() { awk -v a="$1" -v b="$(date +%s.%N)" 'BEGIN { printf "%.2f", b - a }'; }
in_ctr() { buildah run --isolation chroot "${env_args[@]}" -v "$files:/files" "$ctr" -- "$@"; }

# Starts the entrypoint in the background with the volume mounted as $1 ("rw" or "ro").
start_server() {
  # Another server on the port would answer for ours (SMOKE_HTTP_PORT / SMOKE_GRPC_PORT move them).
  if curl -s -o /dev/null "$base/healthz"; then echo "port $http_port is taken" >&2; exit 1; fi
  local t0; t0="$(date +%s.%N)"
  # A replica on a read-only volume runs in the server's read-only mode, as deploy/k8s sets it.
  local mode=(); [ "$1" = ro ] && mode=(-e B2TF_READ_ONLY=1)
  buildah run --isolation chroot "${env_args[@]}" "${mode[@]}" -v "$data:/data:$1" "$ctr" -- "${entrypoint[@]}" >"$work/server.log" 2>"$work/server.err" &
  runner=$!
  for _ in $(seq 1 600); do
    [ "$(curl -s -o /dev/null -w '%{http_code}' "$base/readyz")" = 200 ] && break
    kill -0 "$runner" 2>/dev/null || { cat "$work/server.log" "$work/server.err" >&2; echo "server exited" >&2; exit 1; }
    sleep 0.1
  done
  [ "$(curl -s -o /dev/null -w '%{http_code}' "$base/readyz")" = 200 ] || { cat "$work/server.log" "$work/server.err" >&2; echo "not ready in 60 s" >&2; exit 1; }
  echo "start to ready ($1 volume): $(since "$t0") s; $(head -1 "$work/server.log")"
}

# SIGTERM to b2tf itself (the runner's descendant), as a container engine's stop sends it.
stop_server() {
  local pid="$runner" next
  while [ "$(cat "/proc/$pid/comm" 2>/dev/null)" != b2tf ]; do
    next="$(cat /proc/"$pid"/task/*/children 2>/dev/null | tr ' ' '\n' | grep -m1 . || true)"
    [ -n "$next" ] || { echo "no b2tf process under $runner" >&2; return 1; }
    pid="$next"
  done
  echo "server memory: $(awk '/^VmRSS|^VmHWM/ { printf "%s %d MB  ", $1, $2 / 1024 }' "/proc/$pid/status")"
  kill -TERM "$pid"
  local rc=0
  wait "$runner" || rc=$?
  runner=""
  # stdout alone: buildah relays stdout and stderr through separate pipes, so a log line
  # written before "stopped" can land after it in a shared file.
  tail -1 "$work/server.log" | grep -qx stopped || { cat "$work/server.log" "$work/server.err" >&2; echo "no clean stop" >&2; return 1; }
  [ "$rc" = 0 ] || { echo "exit status $rc after SIGTERM" >&2; return 1; }
  echo "SIGTERM: exit status 0, \"stopped\""
}

estimate() {
  python3 "$here/scene.py" estimate-body "$files/scene" >"$work/estimate.json"
  curl -sf -H 'Content-Type: application/json' --data-binary "@$work/estimate.json" "$base/v1/estimate" >"$work/result.json"
  python3 "$here/scene.py" check "$work/result.json"
}

start_server rw
in_ctr /usr/local/lib/b2tf/healthcheck.sh && echo "HEALTHCHECK command: healthy"

# The sample box and a photo of it at a known pose, made by the image's b2tf.
in_ctr b2tf sample --out /files/sample >/dev/null
pose="$(python3 "$here/scene.py" camera "$files")"
in_ctr b2tf render --mesh /files/sample/sample_box.obj --units m --camera /files/camera.json --pose "$pose" --out /files/scene >/dev/null

# Onboarding as the README shows it (multipart), kept cheap: 42 views × 6 in-plane.
s="$files/sample"
op="$(curl -sf -F object_id=box -F units=m -F level=1 -F in_plane=6 -F mesh=@"$s/sample_box.obj" \
  -F resource=@"$s/sample_box.mtl" -F resource=@"$s/sample_box_m0.png" "$base/v1/objects")"
id="$(python3 -c 'import json,sys; print(json.loads(sys.argv[1])["id"])' "$op")"
t0="$(date +%s.%N)"
while state="$(curl -sf "$base/v1/operations/$id" | python3 -c 'import json,sys; print(json.load(sys.stdin)["state"])')" && [ "$state" = running ]; do sleep 0.5; done
[ "$state" = succeeded ] || { curl -s "$base/v1/operations/$id" >&2; exit 1; }
echo "onboarded box (252 templates) in $(since "$t0") s"
estimate
curl -sf "$base/metrics" >"$work/metrics.txt"
grep -q '^b2tf_requests_total{method="POST",route="/v1/estimate",status="200"} 1$' "$work/metrics.txt" \
  || { echo "/metrics lacks the estimate" >&2; exit 1; }
[ -z "${SMOKE_METRICS_OUT:-}" ] || cp "$work/metrics.txt" "$SMOKE_METRICS_OUT"
# The dashboard (deploy/monitoring) must only use metrics the server has.
python3 "$here/dashboard_metrics.py" "$here/../monitoring/grafana/dashboards/b2tfpose.json" "$work/metrics.txt"
stop_server

# The store on the volume: written by the image's user, readable by b2tf outside the server.
[ -f "$data/objects/box/manifest.json" ] || { echo "no box in the store on the volume" >&2; ls -R "$data" >&2; exit 1; }
[ "$(stat -c %u "$data/objects/box")" = "${uid%%:*}" ] || { echo "store not owned by uid ${uid%%:*}" >&2; exit 1; }
[ "$(ls -A "$data")" = objects ] || { echo "the volume holds more than the store: $(ls -A "$data")" >&2; exit 1; }
buildah run --isolation chroot -v "$data:/data:ro" "$ctr" -- b2tf objects list --json --store dir:///data/objects | grep '"box"' >/dev/null \
  || { echo "b2tf objects list does not show box" >&2; exit 1; }
echo "store on the volume: objects/box, $(du -sh "$data/objects/box" | cut -f1), owned by uid ${uid%%:*}"

# A replica: the same volume read-only.
start_server ro
curl -sf "$base/v1/objects" | grep -q '"box"' || { echo "read-only replica does not list box" >&2; exit 1; }
estimate
# It cannot write the store: an onboarding is refused at once (403, read-only mode), and
# nothing is added.
code="$(curl -s -o "$work/op.json" -w '%{http_code}' -F object_id=box2 -F units=m -F level=0 -F in_plane=1 \
  -F mesh=@"$s/sample_box.obj" -F resource=@"$s/sample_box.mtl" -F resource=@"$s/sample_box_m0.png" "$base/v1/objects")"
[ "$code" = 403 ] && grep -q "read-only" "$work/op.json" || { echo "onboarding on a read-only replica: $code $(cat "$work/op.json")" >&2; exit 1; }
[ "$(ls -A "$data/objects")" = box ] || { echo "the read-only replica wrote: $(ls -A "$data/objects")" >&2; exit 1; }
echo "read-only replica: onboarding refused ($code); store unchanged"
stop_server
echo "smoke test passed: $image"
