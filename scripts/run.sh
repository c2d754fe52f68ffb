#!/usr/bin/env bash
# The main job on the embedded defaults, the way a factory cell uses b2tfpose: start the
# service (`b2tf serve`: HTTP/JSON + gRPC, embedded backbone, lavapipe renderer, SQLite
# store out/demo/objects.db), then `b2tf demo --server` onboards the generated sample
# object through the gRPC API (first run only), renders a photo-like scene of it, estimates
# its pose through the API, prints the pose and its error against the truth and writes
# out/demo/overlay.png. The server is stopped with SIGTERM at the end.
# `b2tf demo` without --server runs the same pipeline in-process.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
source scripts/env.sh
cargo build --release --quiet
mkdir -p out/demo
log=out/demo/server.log
target/release/b2tf serve --http 127.0.0.1:0 --grpc 127.0.0.1:0 --store sqlite://out/demo/objects.db >"$log" 2>&1 &
server=$!
trap 'kill -TERM $server 2>/dev/null; wait $server 2>/dev/null || true' EXIT
# The server prints its addresses once it listens (port 0: free ports).
for _ in $(seq 1 300); do
  grep -q "listening on" "$log" && break
  kill -0 $server 2>/dev/null || { cat "$log" >&2; exit 1; }
  sleep 0.2
done
grpc=$(grep -o 'grpc://[0-9.:]*' "$log" | head -1)
[ -n "$grpc" ] || { echo "server did not report its gRPC address" >&2; cat "$log" >&2; exit 1; }
echo "server: $(grep -m1 "listening on" "$log")"
target/release/b2tf demo --out out/demo --server "$grpc" "$@"
