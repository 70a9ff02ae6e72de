#!/usr/bin/env bash
# Does a run of 1 ms points underrun in the simulator while two processes hog the CPU?
#
# Starts sim-host on a loopback port, two busy loops (bounded by `timeout`), and runs a
# 4,000-point trajectory of 1 ms points (6 joints) with armctl, starting after 100 points
# so that segments are fed while the rest is still being received; then reads STATUS and
# counts runs that ended by underrun. Traffic goes to 127.0.0.1 only.
#
# Usage: scripts/step-load/run.sh [tries]   (default 6; needs `cargo build --release -p
# sim-host -p armctl`). Prints "underruns: N of M".
set -euo pipefail
cd "$(dirname "$0")/../.."
tries="${1:-6}"
bin="${CARGO_TARGET_DIR:-target}/release"
work="$(mktemp -d)"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  rm -rf "$work"
}
trap cleanup EXIT

# 4 s of 1 ms points: each joint ramps out and back at 20 steps/ms.
awk 'BEGIN {
  for (i = 0; i <= 4000; i++) {
    t = i / 1000.0; p = (i < 2000) ? 20 * i : 20 * (4000 - i);
    printf "%.3f,%d,%d,%d,%d,%d,%d\n", t, p, -p, p / 2, p, -p / 2, p
  }
}' > "$work/run.csv"

underruns=0
for try in $(seq 1 "$tries"); do
  port=$((20000 + RANDOM % 20000))
  "$bin/sim-host" --bind "127.0.0.1:$port" --settings "$work/settings-$try.txt" \
    > "$work/sim-$try.log" 2>&1 &
  sim=$!
  pids+=("$sim")
  sleep 0.5
  timeout 8 sh -c 'while :; do :; done' & pids+=("$!")
  timeout 8 sh -c 'while :; do :; done' & pids+=("$!")
  "$bin/armctl" --controller "127.0.0.1:$port" run --quiet --segment-ms 1 \
    --start-after 100 "$work/run.csv" > "$work/run-$try.log" 2>&1 || true
  status="$("$bin/armctl" --controller "127.0.0.1:$port" status 2>&1 || true)"
  executed="$(sed -n 's/^trajectory.* \([0-9]*\) executed$/\1/p' <<<"$status")"
  if grep -q "ended by underrun yes" <<<"$status"; then
    underruns=$((underruns + 1))
    echo "try $try: underrun"
  else
    echo "try $try: complete ($executed points executed)"
  fi
  kill "$sim" 2>/dev/null || true
  wait "$sim" 2>/dev/null || true
done
echo "underruns: $underruns of $tries"
