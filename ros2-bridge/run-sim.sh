#!/usr/bin/env bash
# One command for the ROS 2 bridge against the simulator: starts sim-host (6 joints, on
# 127.0.0.1:8510, throwaway settings) and armctl-ros2 on it with
# ros2-bridge/examples/bridge.json, until Ctrl-C. Extra arguments go to armctl-ros2.
#
#   ros2-bridge/run-sim.sh              # DDS on this machine's network, for MoveIt/ros2 CLI
#   ros2-bridge/run-sim.sh --private    # DDS kept inside a private network namespace
#                                       # (root; unshare -n, multicast on lo only)
set -euo pipefail
cd "$(dirname "$0")/.."

if [ "${1:-}" = "--private" ]; then
  shift
  [ "$(id -u)" = 0 ] || { echo "run-sim.sh: --private needs root (unshare -n)" >&2; exit 2; }
  cargo build -q -p sim-host -p armctl -p armctl-ros2
  exec unshare -n -- bash -c '
    set -euo pipefail
    ip link set lo up; ip link set lo multicast on; ip route add 224.0.0.0/4 dev lo
    RUN_SIM_BUILT=1 exec "$0" "$@"' "$0" "$@"
fi

[ -n "${RUN_SIM_BUILT:-}" ] || cargo build -q -p sim-host -p armctl -p armctl-ros2
bin=${CARGO_TARGET_DIR:-target}/debug
addr=127.0.0.1:8510
work=$(mktemp -d)
sim_pid=""
bridge_pid=""
cleanup() {
  for pid in $bridge_pid $sim_pid; do
    kill "$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
  done
  rm -rf "$work"
}
trap cleanup EXIT INT TERM

"$bin/sim-host" --bind "$addr" --joints 6 --settings "$work/settings.txt" --log-level warn &
sim_pid=$!
for _ in $(seq 50); do
  "$bin/armctl" --controller "$addr" status >/dev/null 2>&1 && break
  kill -0 "$sim_pid" 2>/dev/null || { echo "run-sim.sh: sim-host exited" >&2; exit 1; }
  sleep 0.1
done
echo "run-sim.sh: sim-host on $addr; starting the bridge (Ctrl-C stops both)"
"$bin/armctl-ros2" ros2-bridge/examples/bridge.json --controller "$addr" "$@" &
bridge_pid=$!
wait "$bridge_pid"
