#!/usr/bin/env bash
# Instructions the NUCLEO board's whole step path executes per step pulse, on QEMU's
# Cortex-M7 (mps2-an500) at the board's code generation: the DMA2 stream interrupts
# (flags, the refill through arm-core's StepShared and arm-step's producer, the progress
# and the trajectory task's wake-up through embassy's executor), TIM13's interrupt (its
# wraps every 327.68 us, the compare alarms that make the DIR changes at reversals and end
# the run) and the run's start, amortised over the steps. See README.md.
#
# Builds src/ (board.rs: the board's step path on RAM stand-ins of its registers; main.rs:
# the harness that raises the interrupts in time order), runs it under QEMU with one
# instruction per translation block and the exec trace on (`-singlestep -d exec,nochain`,
# streamed through a FIFO, never written to disk), and counts the traced instructions
# inside each interrupt (between the `step_cost_on_*` and `step_cost_off` markers, less the
# harness's own functions).
#
# Needs: qemu-system-arm (apt-get install qemu-system-arm), the thumbv7em-none-eabihf target
# (rust-toolchain.toml). Usage: run.sh [--detail]  (--detail: the functions the
# instructions go to, per case).
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/../.." && pwd)"
cd "$here"
detail="${1:-}"

# The board's code generation: its profile `fw` (root Cargo.toml) and target flags
# (.cargo/config.toml). Cargo profiles of another workspace cannot be inherited, so the
# opt-levels are mirrored in Cargo.toml here; fail if they drifted apart.
profile_opt_levels() { # file section-prefix
  awk -v p="$2" '/^\[/ { inside = index($0, "[" p) == 1 } inside && /^opt-level/ { print $0 }' "$1"
}
board_levels="$(profile_opt_levels "$root/Cargo.toml" "profile.fw" | sort)"
here_levels="$(profile_opt_levels Cargo.toml "profile.release" | sort)"
if [ "$board_levels" != "$here_levels" ]; then
  echo "step-cost: Cargo.toml's [profile.release*] opt-levels differ from the board's [profile.fw*]:" >&2
  diff <(echo "$board_levels") <(echo "$here_levels") >&2 || true
  exit 1
fi

command -v qemu-system-arm >/dev/null || { echo "qemu-system-arm missing: apt-get install -y qemu-system-arm" >&2; exit 1; }

# Its own directory under the target dir: these flags differ from the board builds'.
export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$root/target}/step-cost"
# The board's codegen flags (.cargo/config.toml's, less its link scripts and path remaps).
export RUSTFLAGS="-C link-arg=-Tlink.x -C target-cpu=cortex-m7 ${STEP_COST_RUSTFLAGS:-}"
cargo build --quiet --release --target thumbv7em-none-eabihf
elf="$CARGO_TARGET_DIR/thumbv7em-none-eabihf/release/step-cost"

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
mkfifo "$work/trace"

# Trace lines: "Trace 0: 0x... [cs_base/pc/flags/cflags] symbol", one per instruction.
# An interrupt is counted from the entry into step_cost_on_<kind> to the entry into
# step_cost_off, leaving out the markers and the harness (harness_*). At each entry into
# step_cost_case: one line "start refill tim13" (instructions) and, with --detail, the
# functions by instructions.
awk -v detail="$detail" '
  function flush(   s) {
    printf "counts %d %d %d\n", c["start"], c["refill"], c["tim13"]
    if (detail != "") {
      for (s in sym) printf "fn %d %s\n", sym[s], s
      print "endfn"
    }
    delete c; delete sym
  }
  $NF != prev && $NF ~ /^step_cost_on_/ { on = 1; kind = substr($NF, 14) }
  $NF != prev && $NF == "step_cost_off" { on = 0 }
  $NF != prev && $NF == "step_cost_case" { flush() }
  on && $NF !~ /^(step_cost_|harness_)/ { c[kind]++; sym[$NF]++ }
  { prev = $NF }' "$work/trace" > "$work/counts" &
counter=$!

timeout 1200 qemu-system-arm -M mps2-an500 -nographic -semihosting -singlestep \
    -d exec,nochain -D "$work/trace" -kernel "$elf" > "$work/out" || {
  echo "step-cost: the harness failed:" >&2; cat "$work/out" >&2; exit 1; }
wait "$counter"

# The harness prints "case N steps S refills R wraps W compares C pended P" per case 1..6.
mapfile -t cases < <(grep '^case ' "$work/out")
mapfile -t counts < <(grep '^counts ' "$work/counts")
[ "${#cases[@]}" -eq 6 ] && [ "${#counts[@]}" -eq 7 ] || {
  echo "step-cost: expected 6 measured cases and 7 counts:" >&2; cat "$work/out" "$work/counts" >&2; exit 1; }

names=("1 joint, 100 kHz" "8 joints in step, 100 kHz" "8 joints, distinct rates 67-100 kHz"
       "1 joint, 1 kHz" "8 joints in step, 1 kHz" "8 joints, distinct rates 0.67-1 kHz")
printf '%-37s %8s %8s %8s %8s   %s\n' "trajectory (10 segments, reversing)" "per step" "start" "refills" "TIM13" "(steps; refills, wraps, alarms)"
for i in 0 1 2 3 4 5; do
  read -r _ _ _ steps _ refills _ wraps _ compares _ pended _ _ <<<"${cases[$i]}"
  read -r _ start refill tim13 <<<"${counts[$((i + 1))]}"
  awk -v n="${names[$i]}" -v s="$steps" -v a="$start" -v r="$refill" -v t="$tim13" \
      -v rc="$refills" -v w="$wraps" -v al="$((compares + pended))" 'BEGIN {
    printf "%-37s %8.1f %8.1f %8.1f %8.1f   (%d; %d, %d, %d)\n", n, (a + r + t) / s, a / s, r / s, t / s, s, rc, w, al }'
done
if [ -n "$detail" ]; then
  awk '/^counts/ { n++ } /^fn / && n > 1 { printf "case %d %8d %s\n", n - 1, $2, $3 }' "$work/counts" \
    | sort -k2,2n -k3,3nr | awk '{ k = $2; if (seen[k]++ < 12) print }'
fi
