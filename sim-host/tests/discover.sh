#!/usr/bin/env bash
# DISCOVER and NET_SET (PROTOCOL.md, "Finding controllers and setting their address") over
# TAP, inside a Linux network namespace this script creates and removes, so that every
# broadcast stays inside it.
#
# Two simulated controllers on one bridge (tap0 and tap1 under br0), as two boards on one
# switch. The host side has two addresses on the bridge: 192.168.7.1 and .200 (two hosts).
#  1. `armctl discover` (limited broadcast, and subnet broadcast) finds both, with their
#     MAC, address, version, joints and owner state;
#  2. discovery takes no owner: another host can take the controller afterwards;
#  3. `armctl net set` is refused from a host that is not the owner (NOT_OWNER) and while
#     the arm runs (BAD_STATE), and stores the address otherwise (shown as pending);
#  4. restarted (a reset), the controller answers at the new address;
#  5. where dnsmasq is installed: `net set --dhcp`, restarted, it takes a leased address.
# Bounded in time; skips (exit 0) where namespaces or TAP devices are not available.
set -euo pipefail
cd "$(dirname "$0")/../.."

script=discover.sh
. tests/scripts/netns.sh
fail() { echo "discover.sh: FAIL: $*"; exit 1; }
[ "$(id -u)" = 0 ] || skip "needs root"
need ip "iproute2 (ip)"
[ -c /dev/net/tun ] || skip "no /dev/net/tun"

target_dir=${CARGO_TARGET_DIR:-target}
cargo build -q -p sim-host -p armctl
sim="$target_dir/debug/sim-host"
armctl="$target_dir/debug/armctl"

ns="armdisc-$$"
work=$(mktemp -d)
declare -A sim_pid=()
dhcp_pid=""
stop_sim() {
  local name=$1
  if [ -n "${sim_pid[$name]:-}" ]; then
    kill "${sim_pid[$name]}" 2>/dev/null || true
    wait "${sim_pid[$name]}" 2>/dev/null || true
    sim_pid[$name]=""
  fi
}
cleanup() {
  for name in "${!sim_pid[@]}"; do stop_sim "$name"; done
  stop_pids "$dhcp_pid"
  ip netns del "$ns" 2>/dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT

in_ns() { ip netns exec "$ns" "$@"; }
ip netns add "$ns" 2>/dev/null || skip "cannot create a network namespace"
lo_multicast in_ns
in_ns ip link add br0 type bridge || skip "cannot create a bridge"
for tap in tap0 tap1; do
  in_ns ip tuntap add name "$tap" mode tap || skip "cannot create a TAP device"
  in_ns ip link set "$tap" master br0
  in_ns ip link set "$tap" up
done
in_ns ip addr add 192.168.7.1/24 dev br0
in_ns ip addr add 192.168.7.200/24 dev br0
in_ns ip link set br0 up
# The limited broadcast (255.255.255.255) needs a route: the bridge, inside the namespace.
in_ns ip route add default dev br0

# start_sim NAME IFACE ARGS...: sim-host NAME on IFACE; waits until it has an address.
# A TAP device just closed by the previous simulator can be busy for a moment: retried.
start_sim() {
  local name=$1 iface=$2
  shift 2
  for _ in $(seq 20); do
    : >"$work/$name.out"
    # Not through in_ns: $! must be the process itself (ip netns exec execs timeout).
    ip netns exec "$ns" timeout 120 "$sim" --tap "$iface" "$@" --settings "$work/$name.txt" \
      --log-level info >"$work/$name.out" 2>"$work/$name.err" &
    sim_pid[$name]=$!
    for _ in $(seq 150); do
      grep -q "listening on $iface" "$work/$name.out" 2>/dev/null && return 0
      kill -0 "${sim_pid[$name]}" 2>/dev/null || break
      sleep 0.1
    done
    wait "${sim_pid[$name]}" 2>/dev/null || true
    sim_pid[$name]=""
    grep -q "resource busy" "$work/$name.err" || break
    sleep 0.25
  done
  cat "$work/$name.err"
  fail "sim-host $name did not come up on $iface"
}

# discover [ARGS...]: armctl discover from 192.168.7.1; prints and returns its output.
discover() {
  in_ns timeout 20 "$armctl" --bind 192.168.7.1:0 discover "$@" | tee "$work/discover.out" >&2
  cat "$work/discover.out"
}
line_of() { grep "^$1:8510 " <<<"$2" || true; }
expect() { # expect TEXT LINE WHAT
  grep -qF -- "$1" <<<"$2" || fail "$3: expected '$1' in: $2"
}

start_sim a tap0 --ip 192.168.7.2/24
start_sim b tap1 --ip 192.168.7.3/24 --joints 4

# 1. Both found by the limited broadcast (the default target) and by the subnet's.
for target in "" "--to 192.168.7.255:8510"; do
  # shellcheck disable=SC2086
  out=$(discover $target)
  a=$(line_of 192.168.7.2 "$out")
  b=$(line_of 192.168.7.3 "$out")
  [ -n "$a" ] && [ -n "$b" ] || fail "discover ${target:-(broadcast)} missed a controller: $out"
  expect "6 joints" "$a" "controller a"
  expect "4 joints" "$b" "controller b"
  expect "free" "$a" "controller a before any host spoke"
  expect "version 1." "$a" "controller a"
  expect "stored 192.168.1.30/24" "$a" "controller a's stored (default) settings"
  mac_a=$(grep -o "mac [0-9a-f:]*" <<<"$a")
  mac_b=$(grep -o "mac [0-9a-f:]*" <<<"$b")
  [ "$mac_a" != "$mac_b" ] || fail "both controllers report $mac_a"
done
echo "discover.sh: broadcast discovery found both controllers ($mac_a, $mac_b)"

# 1b. Issue 21 F7: commands sent to a broadcast address are ignored (no ACK, nothing done),
# a broadcast STOPPED is obeyed. 7 datagrams, each sent once.
broadcast() { # broadcast ADDRESS HEX [WAIT_S]: one datagram with SO_BROADCAST from 192.168.7.1
  in_ns timeout 20 python3 -c '
import socket, sys
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
s.bind(("192.168.7.1", 0))
s.settimeout(float(sys.argv[3]))
s.sendto(bytes.fromhex(sys.argv[2]), (sys.argv[1], 8510))
try:
    print(s.recvfrom(64)[0].hex())
except socket.timeout:
    print("none")
' "$1" "$2" "${3:-0.5}"
}
encode() { "$armctl" frame encode "$@" | grep -Eo '^([0-9a-f]{2} ?)+$' | tr -d ' '; }
pin_on=$(encode --seq 1 pin0-on)
period=$(encode --seq 2 upload-period 1000)
# NET_SET 192.168.7.77/24 (armctl encodes no NET_SET by itself): seq 4, tag 0x21, CRC-8
# (polynomial 0x07, check value 0xF4, docs/PROTOCOL.md section 2).
net_set=$(python3 -c '
body = bytes([4, 0x21, 0, 192, 168, 7, 77, 24, 0, 0, 0, 0])
crc = 0
for b in body:
    crc ^= b
    for _ in range(8):
        crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
print((body + bytes([crc])).hex())')
[ -n "$pin_on" ] && [ -n "$period" ] || fail "armctl frame encode gave no bytes"
for to in 255.255.255.255 192.168.7.255; do
  for hex in "$pin_on" "$period" "$net_set"; do
    reply=$(broadcast "$to" "$hex")
    [ "$reply" = none ] || fail "a command to $to was answered: $reply"
  done
done
for name in a b; do
  if grep -q "PIN0 high" "$work/$name.out" "$work/$name.err"; then
    fail "controller $name executed a broadcast PIN0_ON"
  fi
  grep -q "to a broadcast address was ignored" "$work/$name.out" "$work/$name.err" \
    || fail "controller $name did not log the ignored broadcast"
done
# 5 s for the answer that must come (a loaded machine); 0.5 s above for the ones that must not.
reply=$(broadcast 255.255.255.255 "$(encode --seq 3 stopped)" 5)
[ "$reply" != none ] || fail "a broadcast STOPPED was not ACKed"
grep -q "192.168.7.77" "$work/a.txt" "$work/b.txt" 2>/dev/null \
  && fail "a broadcast NET_SET was stored"
echo "discover.sh: broadcast PIN0_ON, UPLOAD_PERIOD and NET_SET ignored by both, a broadcast STOPPED ACKed"

# 2. Discovery took no owner: the host at .200 takes controller a now.
admin() { in_ns timeout 30 "$armctl" --bind 192.168.7.200:0 --controller 192.168.7.2:8510 "$@"; }
admin reports on >/dev/null || fail "the host at .200 could not take controller a after discovery"
out=$(discover --to 192.168.7.2:8510)
expect "owned by 192.168.7.200" "$(line_of 192.168.7.2 "$out")" "owner after .200's STATUS"

# 3. NET_SET: refused from another host, refused while running, stored otherwise.
if in_ns timeout 30 "$armctl" --bind 192.168.7.1:0 --controller 192.168.7.2:8510 \
     net set --ip 192.168.7.66/24 2>"$work/err.txt"; then
  fail "net set from a host that is not the owner was accepted"
fi
expect "NOT_OWNER" "$(cat "$work/err.txt")" "net set from another host"

# 20 s: still RUNNING at the NET_SET below however slow the machine (it is stopped then).
printf 'time_s,j0\n0.0,0\n20.0,4000\n' >"$work/slow.csv"
ip netns exec "$ns" timeout 30 "$armctl" --bind 192.168.7.200:0 --controller 192.168.7.2:8510 \
  run --quiet "$work/slow.csv" >"$work/run.out" 2>&1 &
run_pid=$!
running=no
for _ in $(seq 100); do
  if grep -q "RUNNING" <<<"$(line_of 192.168.7.2 "$(discover --to 192.168.7.2:8510 2>/dev/null)")"; then
    running=yes
    break
  fi
  sleep 0.1
done
[ "$running" = yes ] || fail "discover never showed controller a RUNNING during armctl run"
if admin net set --ip 192.168.7.66/24 2>"$work/err.txt"; then
  fail "net set while RUNNING was accepted"
fi
expect "BAD_STATE" "$(cat "$work/err.txt")" "net set while running"
admin stop >/dev/null
wait "$run_pid" 2>/dev/null || true

out=$(admin net set --ip 192.168.7.9/24 --gateway 192.168.7.1)
echo "$out" >&2
expect "after its next reset" "$out" "net set"
out=$(discover --to 192.168.7.2:8510)
expect "stored 192.168.7.9/24 via 192.168.7.1 (after reset)" "$(line_of 192.168.7.2 "$out")" "pending address"
grep -q "^ip=192.168.7.9$" "$work/a.txt" || fail "settings file: $(cat "$work/a.txt")"
echo "discover.sh: net set refused from another host and while running, stored otherwise"

# 4. A reset: controller a boots from its stored settings, at the new address.
stop_sim a
start_sim a tap0
out=$(discover)
a=$(line_of 192.168.7.9 "$out")
[ -n "$a" ] || fail "controller a not found at 192.168.7.9 after its restart: $out"
expect "$mac_a" "$a" "same controller"
grep -q "(after reset)" <<<"$a" && fail "still pending after the restart: $a"
[ -z "$(line_of 192.168.7.2 "$out")" ] || fail "controller a still answers at .2"
echo "discover.sh: after a restart controller a answers at 192.168.7.9"
passed=4

# 5. DHCP, where dnsmasq is installed.
skipped=0
if command -v dnsmasq >/dev/null; then
  # The first unicast to a controller just reset: its stack must resolve .200's MAC first,
  # and embassy-net (smoltcp) sends at most one ARP request a second, so the first ACK can
  # take over armctl's default 1 s (10 x 100 ms). 18 attempts stay inside the 2 s
  # duplicate window.
  in_ns timeout 30 "$armctl" --bind 192.168.7.200:0 --controller 192.168.7.9:8510 --attempts 18 \
    net set --dhcp >/dev/null
  stop_sim a
  ip netns exec "$ns" dnsmasq --no-daemon --port=0 --interface=br0 --bind-interfaces \
    --dhcp-range=192.168.7.50,192.168.7.60,255.255.255.0,10m \
    --dhcp-leasefile="$work/leases" --pid-file="$work/dnsmasq.pid" >"$work/dnsmasq.log" 2>&1 &
  dhcp_pid=$!
  start_sim a tap0
  out=$(discover)
  leased=$(grep -o "^192\.168\.7\.[0-9]*:8510 .*$mac_a.*" <<<"$out" | cut -d: -f1 || true)
  case "$leased" in
    192.168.7.5[0-9]|192.168.7.60) ;;
    *) cat "$work/a.err"; fail "controller a not found at a leased address: $out" ;;
  esac
  expect "stored DHCP" "$(line_of "$leased" "$out")" "DHCP settings"
  echo "discover.sh: with --dhcp stored, controller a came back at $leased"
  passed=5
else
  echo "discover.sh: dnsmasq not installed: the DHCP case is skipped"
  skipped=1
fi
echo "discover.sh: $passed passed, 0 failed, $skipped skipped"
