#!/usr/bin/env bash
# Instructions the board's step path executes per step pulse on a Cortex-M4 (QEMU
# mps2-an386): the pulse producer, the DMA refill interrupt body, per-segment setup and the
# run's start, amortised over the steps.
#
# Builds src/main.rs (the refill path over fixed trajectories between two calls to
# `step_cost_mark`), runs it under QEMU with one instruction per translation block and the
# exec trace on, and counts the traced instructions between the marks. The trace is
# streamed through a FIFO, never written to disk.
#
# Needs: qemu-system-arm (apt-get install qemu-system-arm), the thumbv7em-none-eabihf target
# (rust-toolchain.toml). Prints: "instructions per step: 1 joint X, 8 joints Y".
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
cd "$here"
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$here/target}"
# Replaces the workspace's board rustflags (defmt, cortex-m7): this runs on QEMU's M4.
export RUSTFLAGS="-C link-arg=-Tlink.x -C target-cpu=cortex-m4"
cargo build --quiet --release --target thumbv7em-none-eabihf
elf="$CARGO_TARGET_DIR/thumbv7em-none-eabihf/release/step-cost"

command -v qemu-system-arm >/dev/null || { echo "qemu-system-arm missing: apt-get install -y qemu-system-arm" >&2; exit 1; }

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
mkfifo "$work/trace"

# Trace lines: "Trace 0: 0x... [cs_base/pc/flags/cflags] symbol". Between each entry into
# step_cost_mark and the next (odd entry = start of a case, even = its end; the first case
# is a warm-up run and not printed), count the
# instructions outside the harness (functions named harness_*, which stand in for the
# hardware: which DMA half ends first, how long it plays).
awk '$NF == "step_cost_mark" && prev != "step_cost_mark" {
        n++
        if (n % 2 == 1) { inside = 1; count = 0 } else { inside = 0; if (n > 2) print count }
     }
     inside && $NF != "step_cost_mark" && $NF !~ /^harness_/ { count++ }
     { prev = $NF }' "$work/trace" > "$work/counts" &
counter=$!

timeout 600 qemu-system-arm -M mps2-an386 -nographic -semihosting -singlestep \
    -d exec,nochain -D "$work/trace" -kernel "$elf" > "$work/out"
wait "$counter"

# The program prints "steps: <1 joint> <8 joints in step> <8 joints, distinct rates>".
read -r _ s1 s8 s8d < <(grep '^steps:' "$work/out")
mapfile -t counts < "$work/counts"
[ "${#counts[@]}" -eq 3 ] || { echo "expected 3 measured runs, got ${#counts[@]}" >&2; cat "$work/out" >&2; exit 1; }

per() { awk -v i="$1" -v s="$2" 'BEGIN { printf "%.1f", i / s }'; }
echo "instructions per step: 1 joint $(per "${counts[0]}" "$s1"), 8 joints $(per "${counts[1]}" "$s8")"
echo "  (8 joints at distinct rates, edges never coincide: $(per "${counts[2]}" "$s8d");" \
     "raw: ${counts[0]}/$s1, ${counts[1]}/$s8, ${counts[2]}/$s8d instructions/steps)"
