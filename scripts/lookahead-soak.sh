#!/usr/bin/env bash
# Issue 19's acceptance run: the simulated controller under CPU load executes every point
# it holds. Two CPU-bound busy loops per core run meanwhile; then
#   1. RUNS runs of 1000 points of 200 us, uploaded whole before RUNING;
#   2. RUNS runs of 1000 points of 1 ms, streamed (RUNING after the first 24 points).
# After each run, STATUS must show every announced point executed and no underrun.
# Prints, per part, how many runs executed every point. Exit status 1 if any did not.
#
# Usage: scripts/lookahead-soak.sh [RUNS]   (default 50; about 2 minutes on 2 cores)
# Sends only to 127.0.0.1. Every loop is bounded: RUNS runs, each armctl call bounded by
# its own attempts and a 30 s timeout.
set -euo pipefail
cd "$(dirname "$0")/.."
runs="${1:-50}"
port=18519
cargo build --release -q -p sim-host -p armctl
sim="$PWD/target/release/sim-host"
armctl="$PWD/target/release/armctl"
work="$(mktemp -d)"
pids=()
cleanup() {
  for p in "${pids[@]}"; do kill "$p" 2>/dev/null || true; done
  wait 2>/dev/null || true
  [[ -n "${KEEP:-}" ]] || rm -rf "$work"; [[ -n "${KEEP:-}" ]] && echo "kept $work"
}
trap cleanup EXIT

# The trajectories: 3 joints moving, 1000 points each.
python3 - "$work" <<'EOF'
import sys
d = sys.argv[1]
for name, dt in (("p200us.csv", 0.0002), ("p1ms.csv", 0.001)):
    with open(f"{d}/{name}", "w") as f:
        f.write("time_s,j0,j1,j2\n")
        for k in range(1001):
            f.write(f"{k * dt:.4f},{k},{-k},{k // 2}\n")
EOF

busy=$(( 2 * $(nproc) ))
loop='while :; do :; done'
echo "load: $busy loops of \`$loop\` (2 per core, $(nproc) cores)"
for _ in $(seq "$busy"); do
  bash -c "$loop" &
  pids+=($!)
done

"$sim" --bind "127.0.0.1:$port" --settings "$work/settings.txt" --log-level warn \
  >"$work/sim.log" 2>&1 &
pids+=($!)
for _ in $(seq 50); do
  "$armctl" --controller "127.0.0.1:$port" status >/dev/null 2>&1 && break
  sleep 0.1
done

# One run, then its STATUS: "ok" when every announced point was executed, no underrun.
one_run() {
  local file="$1" segment_ms="$2"; shift 2
  local rc=0
  # Every run starts from zero (the last one ended at its end point).
  timeout 10 "$armctl" --controller "127.0.0.1:$port" set-location 0 0 0 0 0 0 \
    >"$work/run.out" 2>&1 || true
  timeout 30 "$armctl" run --controller "127.0.0.1:$port" --quiet --segment-ms "$segment_ms" \
    "$@" "$file" >"$work/run.out" 2>&1 || rc=$?
  timeout 10 "$armctl" --controller "127.0.0.1:$port" status >"$work/status.out" 2>&1 || true
  local line announced executed underrun
  line="$(grep '^trajectory' "$work/status.out" || true)"
  announced="$(sed -E 's/.* ([0-9]+) announced.*/\1/' <<<"$line")"
  executed="$(sed -E 's/.* ([0-9]+) executed.*/\1/' <<<"$line")"
  underrun="$(grep -c 'ended by underrun yes' "$work/status.out" || true)"
  if [[ "$rc" == 0 && -n "$line" && "$announced" == "1000" && "$executed" == "1000" && "$underrun" == "0" ]]; then
    echo ok
  else
    echo "FAILED: ${line:-no STATUS}; underrun $underrun; armctl exit $rc: $(tail -1 "$work/run.out")"
  fi
}

failed=0
part() {
  local title="$1"; shift
  local good=0 r
  for i in $(seq "$runs"); do
    r="$(one_run "$@")"
    if [[ "$r" == ok ]]; then
      good=$((good + 1))
    else
      echo "  run $i: $r"
    fi
  done
  echo "$title: $good of $runs runs executed every point (1000 of 1000, no underrun)"
  [[ "$good" == "$runs" ]] || failed=1
}

echo "load average before: $(cut -d' ' -f1-3 /proc/loadavg)"
part "200 us points, uploaded whole before RUNING" "$work/p200us.csv" 0.2
part "1 ms points, streamed (RUNING after 24)" "$work/p1ms.csv" 1 --start-after 24
echo "load average after: $(cut -d' ' -f1-3 /proc/loadavg)"
exit "$failed"
