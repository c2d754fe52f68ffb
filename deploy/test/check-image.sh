#!/usr/bin/env bash
# What every b2tfpose image must be, CPU or GPU alike, read from the built image:
#   check-image.sh IMAGE
# non-root user, `b2tf serve` entrypoint, ports 50051/8080, the /data volume, a HEALTHCHECK
# on /readyz, the OCI labels, settings from B2TF_* only (no key, token or password baked
# in, no build-time CA bundle left behind), and a b2tf and ONNX Runtime library that load.
set -euo pipefail
image="$1"
fail() { echo "$image: $*" >&2; exit 1; }
cfg="$(buildah inspect --type image "$image")"
field() { python3 -c 'import json, sys; d = json.load(sys.stdin); print(json.dumps(eval(sys.argv[1], {"d": d})))' "$1" <<<"$cfg"; }
[ "$(field 'd["Docker"]["config"]["User"]')" = '"10001:10001"' ] || fail "user is not 10001:10001"
[ "$(field 'd["Docker"]["config"]["Entrypoint"]')" = '["/usr/local/bin/b2tf", "serve"]' ] || fail "entrypoint is not b2tf serve"
[ "$(field 'sorted(d["Docker"]["config"]["ExposedPorts"])')" = '["50051/tcp", "8080/tcp"]' ] || fail "ports"
[ "$(field 'sorted(d["Docker"]["config"]["Volumes"])')" = '["/data"]' ] || fail "volume"
field 'd["Docker"]["config"]["Healthcheck"]["Test"]' | grep -q healthcheck.sh || fail "no HEALTHCHECK"
for label in title description version revision source licenses; do
  field 'd["Docker"]["config"]["Labels"]' | grep -q "\"org.opencontainers.image.$label\"" || fail "no OCI label $label"
done
env="$(field 'd["Docker"]["config"]["Env"]')"
grep -qiE 'KEY=|TOKEN|PASSWORD|SECRET' <<<"$env" && fail "a secret-like variable in the image: $env"
grep -q '"B2TF_STORE=dir:///data/objects"' <<<"$env" || fail "store is not on /data"

ctr="$(buildah from --pull=never "$image")"
trap 'buildah rm "$ctr" >/dev/null' EXIT
in_ctr() { buildah run --isolation chroot "$ctr" -- "$@"; }
buildah run --isolation chroot --user root "$ctr" -- sh -c '! ls -d /run/secrets/* /root/.cargo /usr/local/cargo /src 2>/dev/null' 2>/dev/null \
  || fail "build-time files left in the image"
in_ctr b2tf --version >/dev/null || fail "b2tf does not run"
# The library B2TF_ORT_LIB names loads; a provider's unmet libraries (CUDA on a stand-in
# base) are listed: the real base must supply them.
in_ctr sh -c 'ldd "$B2TF_ORT_LIB" | grep "not found"' 2>/dev/null && fail "ONNX Runtime library: libraries missing"
for lib in $(in_ctr sh -c 'ls /usr/local/lib/onnxruntime/libonnxruntime_providers_*.so'); do
  missing="$(in_ctr sh -c "ldd $lib | awk '/not found/ { print \$1 }' | tr '\n' ' '")"
  [ -z "$missing" ] || echo "  $(basename "$lib") needs from the base: $missing"
done
echo "$image: $(buildah images --format '{{.Size}}' "$image"), user 10001, b2tf serve, :50051 :8080, /data, HEALTHCHECK, OCI labels, no secrets; $(in_ctr b2tf --version)"
