#!/usr/bin/env bash
# sim-host over a TAP device, on the same embassy-net code path as the board, inside a
# Linux network namespace this script creates and removes. A python3 client in the
# namespace sends STATUS to 192.168.7.2:8510 and checks the ACK and the STATUS report.
# Bounded in time; skips (exit 0) where namespaces or TAP devices are not available.
set -euo pipefail
cd "$(dirname "$0")/../.."

skip() { echo "tap.sh: SKIP: $*"; exit 0; }
[ "$(id -u)" = 0 ] || skip "needs root"
command -v ip >/dev/null || skip "needs iproute2 (ip)"
command -v python3 >/dev/null || skip "needs python3"
[ -c /dev/net/tun ] || skip "no /dev/net/tun"

target_dir=${CARGO_TARGET_DIR:-target}
cargo build -q -p sim-host
bin="$target_dir/debug/sim-host"
[ -x "$bin" ] || { echo "tap.sh: $bin missing"; exit 1; }

ns="armsim-$$"
work=$(mktemp -d)
sim_pid=""
cleanup() {
  if [ -n "$sim_pid" ]; then kill "$sim_pid" 2>/dev/null || true; wait "$sim_pid" 2>/dev/null || true; fi
  ip netns del "$ns" 2>/dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT
ip netns add "$ns" 2>/dev/null || skip "cannot create a network namespace"
ip netns exec "$ns" ip tuntap add name tap0 mode tap || skip "cannot create a TAP device"
ip netns exec "$ns" ip addr add 192.168.7.1/24 dev tap0
ip netns exec "$ns" ip link set tap0 up
ip netns exec "$ns" ip link set lo up

ip netns exec "$ns" timeout 60 "$bin" --tap tap0 --ip 192.168.7.2/24 \
  --settings "$work/settings.txt" --log-level info >"$work/out" 2>"$work/err" &
sim_pid=$!

for _ in $(seq 100); do
  grep -q "listening on tap0" "$work/out" 2>/dev/null && break
  kill -0 "$sim_pid" 2>/dev/null || { cat "$work/err"; echo "tap.sh: sim-host exited"; exit 1; }
  sleep 0.1
done
grep -q "listening on tap0" "$work/out" || { cat "$work/err"; echo "tap.sh: sim-host not up"; exit 1; }

ip netns exec "$ns" timeout 30 python3 - <<'PY'
import socket, struct, sys, time

def crc8(data):
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc

controller = ("192.168.7.2", 8510)
sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
sock.bind(("192.168.7.1", 0))
sock.settimeout(0.5)
frame = bytes([42, 0x15])
frame += bytes([crc8(frame)])
ack = status = None
# The first tries may go while ARP resolves: resend, a bounded number of times.
for attempt in range(20):
    sock.sendto(frame, controller)
    deadline = time.time() + 0.5
    while time.time() < deadline and (ack is None or status is None):
        try:
            data, _ = sock.recvfrom(2048)
        except socket.timeout:
            break
        if crc8(data[:-1]) != data[-1]:
            sys.exit("tap.sh: report with a bad CRC: " + data.hex())
        tag = data[1]
        if tag == 0x14 and data[0] == 42:
            ack = data
        elif tag == 0x15:
            status = data
    if ack is not None and status is not None:
        break
if ack is None:
    sys.exit("tap.sh: no ACK from 192.168.7.2:8510")
acked_tag, code, state = ack[2], ack[3], ack[4]
if (acked_tag, code, state) != (0x15, 0, 3):
    sys.exit("tap.sh: unexpected ACK " + ack.hex())
if status is None:
    sys.exit("tap.sh: no STATUS report")
version, joints = tuple(status[2:5]), status[5]
print(f"tap.sh: ACK OK (state STOPPED), STATUS version {version} joints {joints}")
if joints != 6:
    sys.exit("tap.sh: expected 6 joints")
PY
echo "tap.sh: 1 passed, 0 failed"
