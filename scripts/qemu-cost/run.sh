#!/usr/bin/env bash
# Cortex-M7 instructions the firmware executes under QEMU (mps2-an500) to handle
#  - one 12-point PENDING datagram, from the LAN9118 interrupt to its ACK written into the
#    NIC's TX FIFO, and
#  - one STOPPED during a run, from the LAN9118 interrupt to the step output stopped (the
#    producer's stop, which plays the edges up to it, lowering every STEP line).
#
# Builds the firmware (`cargo qemu-fw`, the NUCLEO's release profile), runs it with one
# instruction per translation block and the exec trace on (`-singlestep -d exec,nochain`,
# streamed through a FIFO, never written to disk), and counts the traced instructions
# between the marks `qemu_mark_nic_irq` and `qemu_mark_frame_sent` /
# `qemu_mark_steps_stopped` (firmware/qemu-mps2/src/marks.rs). drive.py sends each measured
# datagram alone after a quiet second; location reports are off. Counts include the
# interrupt entries, the executor, embassy-net and the driver's PIO copies.
#
# Needs: qemu-system-arm, python3, the thumbv7em-none-eabihf target. Prints medians and
# ranges over REPEATS (default 5) datagrams of each kind.
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/../.." && pwd)"
repeats="${1:-5}"
cd "$root"
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$root/target}"
command -v qemu-system-arm >/dev/null || { echo "qemu-system-arm missing: apt-get install -y qemu-system-arm" >&2; exit 1; }
cargo qemu-fw --quiet
cargo build --quiet --release -p armctl
elf="$CARGO_TARGET_DIR/thumbv7em-none-eabihf/release/firmware-qemu"
armctl="$CARGO_TARGET_DIR/release/armctl"

work="$(mktemp -d)"
qemu_pid=""
cleanup() {
  [ -n "$qemu_pid" ] && kill "$qemu_pid" 2>/dev/null || true
  wait 2>/dev/null || true
  rm -rf "$work"
}
trap cleanup EXIT
mkfifo "$work/trace"
: > "$work/counts"

# Trace lines: "Trace 0: 0x... [cs_base/pc/flags/cflags] symbol". A NIC interrupt opens an
# interval; the next frame sent closes it as "ack", the next steps-stopped mark (before or
# after that frame) as "stop". Consecutive lines in one mark function count once.
awk '
  $NF != prev && $NF == "qemu_mark_nic_irq" { if (!ack_open) ack_start = NR; ack_open = 1; stop_start = NR }
  $NF != prev && $NF == "qemu_mark_frame_sent" && ack_open { print "ack", NR - ack_start; fflush(); ack_open = 0 }
  $NF != prev && $NF == "qemu_mark_steps_stopped" && stop_start { print "stop", NR - stop_start; fflush(); stop_start = 0 }
  { prev = $NF }' "$work/trace" >> "$work/counts" &

port="$(python3 -c 'import socket; s=socket.socket(socket.AF_INET, socket.SOCK_DGRAM); s.bind(("127.0.0.1",0)); print(s.getsockname()[1])')"
qemu-system-arm -M mps2-an500 -display none -monitor none \
  -semihosting-config enable=on,target=native -kernel "$elf" \
  -nic "user,model=lan9118,hostfwd=udp:127.0.0.1:$port-:8510" \
  -serial "file:$work/uart0.log" -serial null \
  -singlestep -d exec,nochain -D "$work/trace" &
qemu_pid=$!

# Boot under full tracing is slow: wait for the log line that says the stack is up.
for _ in $(seq 1 600); do
  grep -q "listening on" "$work/uart0.log" 2>/dev/null && break
  sleep 0.1
done
grep -q "listening on" "$work/uart0.log" || { echo "firmware did not come up:" >&2; cat "$work/uart0.log" >&2; exit 1; }

out="$(python3 "$here/drive.py" "$armctl" "127.0.0.1:$port" "$work/counts" "$repeats")" || {
  echo "driving the firmware failed; log:" >&2; cat "$work/uart0.log" >&2; exit 1; }
if grep -qE "PANIC|HARDFAULT|FATAL" "$work/uart0.log"; then cat "$work/uart0.log" >&2; exit 1; fi

stats() { tr ' ' '\n' | sort -n | awk '{ v[NR] = $1 } END { printf "median %d (min %d, max %d, n %d)", v[int((NR + 1) / 2)], v[1], v[NR], NR }'; }
pending="$(grep '^pending:' <<<"$out" | cut -d' ' -f2-)"
stopped="$(grep '^stopped:' <<<"$out" | cut -d' ' -f2-)"
echo "instructions, 12-point PENDING, NIC interrupt to ACK sent: $(stats <<<"$pending")"
echo "instructions, STOPPED, NIC interrupt to step output stopped: $(stats <<<"$stopped")"
authenticated="$(grep '^authenticated:' <<<"$out" | cut -d' ' -f2-)"
echo "instructions, 12-point authenticated PENDING (issue 21), NIC interrupt to sealed ACK sent: $(stats <<<"$authenticated")"
echo "  raw: pending $pending; stopped $stopped; authenticated $authenticated"
# What authentication costs, and the upload rate the CPU allows at 480 MHz (README's
# 1.3 cycles per instruction), with and without it.
median() { tr ' ' '\n' | sort -n | awk '{ v[NR] = $1 } END { print v[int((NR + 1) / 2)] }'; }
p="$(median <<<"$pending")"; a="$(median <<<"$authenticated")"
awk -v p="$p" -v a="$a" 'BEGIN {
  printf "authentication: +%d instructions per 12-point PENDING (%.0f per point); ", a - p, (a - p) / 12
  printf "at 480 MHz and 1.3 cycles/instruction the whole path allows %.0f points/s authenticated (%.0f plain)\n", 12 * 480e6 / (1.3 * a), 12 * 480e6 / (1.3 * p)
}'
