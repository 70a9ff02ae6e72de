# Shell helpers for the scripts that test inside a network namespace of their own
# (sim-host/tests/tap.sh and discover.sh, tests/qemu/tap.sh, ros2-bridge/tests/dds.sh).
# Source it from the repository root after setting `script` (the name messages start with).

# skip WHY...: this machine cannot run the script: say why and exit 0.
skip() { echo "$script: SKIP: $*"; exit 0; }

# need TOOL WHAT: skip, saying it needs WHAT, unless TOOL is on PATH.
need() { command -v "$1" >/dev/null || skip "needs $2"; }

# stop_pids PID...: ends each process (started by the calling script) and waits for it;
# empty arguments are ignored.
stop_pids() {
  local pid
  for pid in "$@"; do
    [ -n "$pid" ] || continue
    kill "$pid" 2>/dev/null || true
    wait "$pid" 2>/dev/null || true
  done
}

# netns_with_tap NS ADDR/PREFIX...: creates network namespace NS (the caller's cleanup
# removes it) with a TAP device tap0 that has each address, tap0 and lo up. Skips where
# namespaces or TAP devices are not available.
netns_with_tap() {
  local ns=$1 address
  shift
  ip netns add "$ns" 2>/dev/null || skip "cannot create a network namespace"
  ip netns exec "$ns" ip tuntap add name tap0 mode tap || skip "cannot create a TAP device"
  for address in "$@"; do ip netns exec "$ns" ip addr add "$address" dev tap0; done
  ip netns exec "$ns" ip link set tap0 up
  ip netns exec "$ns" ip link set lo up
}

# lo_multicast [PREFIX...]: lo up with multicast and the route for 224.0.0.0/4, so that
# DDS discovery and DISCOVER broadcasts stay on it. PREFIX runs each command in a
# namespace (e.g. `ip netns exec NS`); without it, in the current one.
lo_multicast() {
  "$@" ip link set lo up
  "$@" ip link set lo multicast on
  "$@" ip route add 224.0.0.0/4 dev lo
}
