#!/usr/bin/env bash
# sim-host over a TAP device, on the same embassy-net code path as the board, inside a
# Linux network namespace this script creates and removes. A python3 client in the
# namespace sends STATUS to the controller and checks the ACK and the STATUS report:
# first with a static address (--ip 192.168.7.2/24), then, where dnsmasq is installed,
# with an address from DHCP (--ip dhcp). Bounded in time; skips (exit 0) where namespaces
# or TAP devices are not available.
set -euo pipefail
cd "$(dirname "$0")/../.."

script=tap.sh
. tests/scripts/netns.sh
[ "$(id -u)" = 0 ] || skip "needs root"
need ip "iproute2 (ip)"
need python3 python3
[ -c /dev/net/tun ] || skip "no /dev/net/tun"

target_dir=${CARGO_TARGET_DIR:-target}
cargo build -q -p sim-host
bin="$target_dir/debug/sim-host"
[ -x "$bin" ] || { echo "tap.sh: $bin missing"; exit 1; }

ns="armsim-$$"
work=$(mktemp -d)
sim_pid=""
dhcp_pid=""
stop_sim() {
  stop_pids "$sim_pid"
  sim_pid=""
}
cleanup() {
  stop_sim
  stop_pids "$dhcp_pid"
  ip netns del "$ns" 2>/dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT
netns_with_tap "$ns" 192.168.7.1/24

# start_sim ARGS...: runs sim-host on tap0 in the namespace; waits until it has an address.
start_sim() {
  : >"$work/out"
  ip netns exec "$ns" timeout 60 "$bin" --tap tap0 "$@" \
    --settings "$work/settings.txt" --log-level info >"$work/out" 2>"$work/err" &
  sim_pid=$!
  for _ in $(seq 150); do
    grep -q "listening on tap0" "$work/out" 2>/dev/null && return 0
    kill -0 "$sim_pid" 2>/dev/null || { cat "$work/err"; echo "tap.sh: sim-host exited"; exit 1; }
    sleep 0.1
  done
  cat "$work/err"
  echo "tap.sh: sim-host got no address"
  exit 1
}

# status_exchange ADDR: STATUS to ADDR:8510 from inside the namespace; checks ACK and report.
status_exchange() {
  ip netns exec "$ns" timeout 30 python3 - "$1" <<'PY'
import socket, sys, time
sys.path.insert(0, "tests/scripts")
from arm_frames import crc8

controller = (sys.argv[1], 8510)
sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
sock.bind(("192.168.7.1", 0))
sock.settimeout(0.5)
ack = status = None
# The first tries may go while ARP resolves: resend (a new seq each time, so that none is
# taken for a duplicate), a bounded number of times.
for attempt in range(20):
    seq = 40 + attempt
    frame = bytes([seq, 0x15])
    frame += bytes([crc8(frame)])
    sock.sendto(frame, controller)
    deadline = time.time() + 0.5
    while time.time() < deadline and (ack is None or status is None):
        try:
            data, _ = sock.recvfrom(2048)
        except socket.timeout:
            break
        if crc8(data[:-1]) != data[-1]:
            sys.exit("tap.sh: report with a bad CRC: " + data.hex())
        if data[1] == 0x14:
            ack = data
        elif data[1] == 0x15:
            status = data
    if ack is not None and status is not None:
        break
if ack is None:
    sys.exit(f"tap.sh: no ACK from {controller[0]}:8510")
acked_tag, code, state = ack[2], ack[3], ack[4]
if (acked_tag, code, state) != (0x15, 0, 3):
    sys.exit("tap.sh: unexpected ACK " + ack.hex())
if status is None:
    sys.exit("tap.sh: no STATUS report")
version, joints = tuple(status[2:5]), status[5]
print(f"tap.sh: {controller[0]}: ACK OK (state STOPPED), STATUS version {version} joints {joints}")
if joints != 6:
    sys.exit("tap.sh: expected 6 joints")
PY
}

passed=0
start_sim --ip 192.168.7.2/24
status_exchange 192.168.7.2
passed=$((passed + 1))
stop_sim

skipped=0
if command -v dnsmasq >/dev/null; then
  ip netns exec "$ns" dnsmasq --no-daemon --port=0 --interface=tap0 --bind-interfaces \
    --dhcp-range=192.168.7.50,192.168.7.60,255.255.255.0,10m \
    --dhcp-leasefile="$work/leases" --pid-file="$work/dnsmasq.pid" >"$work/dnsmasq.log" 2>&1 &
  dhcp_pid=$!
  start_sim --ip dhcp
  leased=$(grep -o "tap: address 192\.168\.7\.[0-9]*" "$work/err" | head -1 | cut -d' ' -f3)
  case "$leased" in
    192.168.7.5[0-9]|192.168.7.60) ;;
    *) cat "$work/err"; echo "tap.sh: DHCP address not from the server's range: '$leased'"; exit 1 ;;
  esac
  status_exchange "$leased"
  passed=$((passed + 1))
  stop_sim
else
  echo "tap.sh: dnsmasq not installed: the DHCP case is skipped"
  skipped=1
fi
echo "tap.sh: $passed passed, 0 failed, $skipped skipped"
