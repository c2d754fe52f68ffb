#!/usr/bin/env bash
# Fuzzes every target (or the ones named) for SECONDS each, one after the other, and prints
# per target the executions and the findings (crash, leak, timeout and out-of-memory inputs
# libFuzzer saved under fuzz/artifacts/<target>/).
#
#   fuzz/run.sh SECONDS [TARGET...]
#
# The toolchain is stable: cargo fuzz passes nightly-only flags (-Zsanitizer=address, ...),
# which RUSTC_BOOTSTRAP=1 lets stable rustc take. The working corpus grows in
# fuzz/corpus/<target>/ (not checked in) from the seeds in fuzz/seeds/<target>/ and the
# failures kept in fuzz/regressions/<target>/. A finding stops its target's run (libFuzzer
# stops at the first); fix it, copy the input to fuzz/regressions/<target>/, run again.
set -euo pipefail
cd "$(dirname "$0")"
source ../scripts/env.sh
seconds=${1:?usage: fuzz/run.sh SECONDS [TARGET...]}
shift
command -v cargo-fuzz >/dev/null || cargo install --locked cargo-fuzz
export RUSTC_BOOTSTRAP=1
targets=("$@")
[ ${#targets[@]} -gt 0 ] || mapfile -t targets < <(cargo fuzz list)

# NO_BUILD=1 runs the binaries as they are (e.g. while a rebuild runs beside).
[ -n "${NO_BUILD:-}" ] || nice -n 15 cargo fuzz build
bin=target/x86_64-unknown-linux-gnu/release

summary=()
for t in "${targets[@]}"; do
  mkdir -p "corpus/$t" "artifacts/$t" logs
  dirs=("corpus/$t" "seeds/$t")
  [ -d "regressions/$t" ] && dirs+=("regressions/$t")
  before=$(ls "artifacts/$t" | wc -l)
  # rss and single-allocation limits of 2 GiB flag unbounded allocations; 10 s a run
  # flags hangs.
  nice -n 15 "$bin/$t" "${dirs[@]}" -max_total_time="$seconds" -timeout=10 \
    -rss_limit_mb=2048 -malloc_limit_mb=2048 -print_final_stats=1 \
    -artifact_prefix="artifacts/$t/" >"logs/$t.log" 2>&1 || true
  runs=$(grep -o 'stat::number_of_executed_units: *[0-9]*' "logs/$t.log" | grep -o '[0-9]*$' | tail -1)
  found=$(ls "artifacts/$t" | grep -cvE '^slow-unit-' || true)
  new=$(( $(ls "artifacts/$t" | wc -l) - before ))
  summary+=("$(printf '%-16s %12s executions  %3s findings (%s new this run)' "$t" "${runs:-?}" "$found" "$new")")
  echo "${summary[-1]}"
done
echo
echo "fuzzed ${#targets[@]} target(s) for ${seconds} s each:"
printf '%s\n' "${summary[@]}"
