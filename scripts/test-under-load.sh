#!/usr/bin/env bash
# Issue 19: `cargo test` passes again and again on a loaded machine. Runs `cargo test`
# RUNS times in a row (default 20) with two CPU-bound busy loops per core beside it, and
# prints, per run, whether it passed, how long it took and, for a failure, the failing
# tests. Exit status 1 if any run failed.
#
# Usage: scripts/test-under-load.sh [RUNS]
# The tests build first, unloaded (a build is not what is measured). Every loop is bounded:
# RUNS runs; the busy loops are killed on exit.
set -euo pipefail
cd "$(dirname "$0")/.."
runs="${1:-20}"
log_dir="$(mktemp -d)"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
}
trap cleanup EXIT

cargo test --no-run -q 2>/dev/null || cargo test --no-run

busy=$(( 2 * $(nproc) ))
loop='while :; do :; done'
echo "load: $busy loops of \`$loop\` (2 per core, $(nproc) cores); logs in $log_dir"
for _ in $(seq "$busy"); do
  bash -c "$loop" &
  pids+=($!)
done

failed=0
for i in $(seq "$runs"); do
  start=$(date +%s)
  if cargo test -q >"$log_dir/run-$i.log" 2>&1; then
    verdict=passed
  else
    verdict=FAILED
    failed=$((failed + 1))
  fi
  passed=$(grep -Eo '[0-9]+ passed' "$log_dir/run-$i.log" | awk '{s += $1} END {print s + 0}')
  echo "run $i of $runs: $verdict in $(( $(date +%s) - start )) s ($passed tests passed; load $(cut -d' ' -f1 /proc/loadavg))"
  if [[ "$verdict" == FAILED ]]; then
    grep -E '^(test .* FAILED|---- .* stdout ----|thread .* panicked)' "$log_dir/run-$i.log" | head -20 || true
  fi
done
echo "$(( runs - failed )) of $runs runs of cargo test passed under load"
[[ "$failed" == 0 ]]
