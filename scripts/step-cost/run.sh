#!/usr/bin/env bash
# Instructions the NUCLEO board's whole step path executes per step pulse, on QEMU's
# Cortex-M7 (mps2-an500) at the board's code generation: the DMA2 stream interrupts
# (flags, the refill through arm-core's StepShared and arm-step's producer, the progress
# and the trajectory task's wake-up through embassy's executor), TIM13's interrupt (its
# wraps every 327.68 us, the compare alarms that make the DIR changes at reversals), the
# step service interrupt (the run's end) and the run's start, amortised over the steps.
# Then the longest span, per section, during which the DIR interrupt is masked. See
# README.md.
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

# The masked spans (issue 20), from llvm-tools' objdump (fail loudly without it):
# - PRIMASK: every `cpsid i` (a critical section's entry: every interrupt held off, the
#   DIR interrupt too) and every `msr primask` (its exit, restoring the state before);
# - BASEPRI: every `msr basepri_max` (the step lock's entry: it masks the lock's priority
#   and below) and every `msr basepri` (its exit, restoring the mask before). Whether such
#   a span masks the DIR interrupt depends on the two priorities, which the harness prints
#   from the board's constants ("levels step-lock L dir D"): it does only if L <= D.
objdump_tool="$(rustc --print sysroot)/lib/rustlib/$(rustc -vV | sed -n 's/^host: //p')/bin/llvm-objdump"
[ -x "$objdump_tool" ] || { echo "step-cost: $objdump_tool missing; run 'rustup component add llvm-tools'" >&2; exit 1; }
"$objdump_tool" -d "$elf" | awk '
  NF >= 2 && $NF == "i" && $(NF - 1) == "cpsid" { sub(":", "", $1); print "on", $1 }
  NF >= 3 && $(NF - 1) == "primask," && $(NF - 2) == "msr" { sub(":", "", $1); print "off", $1 }
  NF >= 3 && $(NF - 1) == "basepri_max," && $(NF - 2) == "msr" { sub(":", "", $1); print "bon", $1 }
  NF >= 3 && $(NF - 1) == "basepri," && $(NF - 2) == "msr" { sub(":", "", $1); print "boff", $1 }' > "$work/mask_pcs"
grep -q '^on ' "$work/mask_pcs" || { echo "step-cost: no cpsid found in $elf" >&2; exit 1; }
grep -q '^off ' "$work/mask_pcs" || { echo "step-cost: no msr primask found in $elf" >&2; exit 1; }
if grep -q '^bon ' "$work/mask_pcs" && ! grep -q '^boff ' "$work/mask_pcs"; then
  echo "step-cost: msr basepri_max without any msr basepri in $elf" >&2; exit 1
fi

# Trace lines: "Trace 0: 0x... [cs_base/pc/flags/cflags] symbol", one per instruction.
# An interrupt is counted from the entry into step_cost_on_<kind> to the entry into
# step_cost_off, leaving out the markers and the harness (harness_*). At each entry into
# step_cost_case: one line "start refill tim13" (instructions) and, with --detail, the
# functions by instructions.
awk -v detail="$detail" -v maskfile="$work/mask_pcs" '
  BEGIN {
    while ((getline line < maskfile) > 0) {
      split(line, a, " "); pc = a[2]; sub(/^0+/, "", pc)
      if (a[1] == "on") onpc[pc] = 1
      else if (a[1] == "off") offpc[pc] = 1
      else if (a[1] == "bon") bonpc[pc] = 1
      else boffpc[pc] = 1
    }
  }
  function flush(   s, k) {
    printf "counts %d %d %d %d\n", c["start"], c["refill"], c["tim13"], c["service"]
    for (k in seen) printf "mask %s %d %s %d %s %d\n", k, longest[k] + 0, (k in where ? where[k] : "-"), blongest[k] + 0, (k in bwhere ? bwhere[k] : "-"), maxrun[k] + 0
    delete longest; delete where; delete blongest; delete bwhere; delete seen; delete maxrun
    if (detail != "") {
      for (s in sym) printf "fn %d %s\n", sym[s], s
      print "endfn"
    }
    delete c; delete sym
  }
  $NF != prev && $NF ~ /^step_cost_on_/ { on = 1; kind = substr($NF, 14); run = 0 }
  $NF != prev && $NF == "step_cost_off" { on = 0; if (run > maxrun[kind]) maxrun[kind] = run }
  on && $NF !~ /^(step_cost_|harness_)/ { run++ }
  $NF != prev && $NF == "step_cost_case" { flush() }
  on && $NF !~ /^(step_cost_|harness_)/ { c[kind]++; sym[$NF]++ }
  # Masked spans inside the measured code: from a cpsid to the msr that ends the
  # outermost critical section (nested ones restore "masked"), in instructions; the same
  # for BASEPRI, from the outermost msr basepri_max to the msr basepri that restores it.
  on {
    seen[kind] = 1
    split($4, f, "/"); pc = f[2]; sub(/^0+/, "", pc)
    if (depth > 0) span++
    if (bdepth > 0) bspan++
    if (pc in onpc) { if (depth++ == 0) { span = 1; from = $NF } }
    else if ((pc in offpc) && depth > 0 && --depth == 0) {
      if (span > longest[kind]) { longest[kind] = span; where[kind] = from }
    }
    if (pc in bonpc) { if (bdepth++ == 0) { bspan = 1; bfrom = $NF } }
    else if ((pc in boffpc) && bdepth > 0 && --bdepth == 0) {
      if (bspan > blongest[kind]) { blongest[kind] = bspan; bwhere[kind] = bfrom }
    }
  }
  !on { depth = 0; bdepth = 0 }
  { prev = $NF }' "$work/trace" > "$work/counts" &
counter=$!

timeout 1200 qemu-system-arm -M mps2-an500 -nographic -semihosting -singlestep \
    -d exec,nochain -D "$work/trace" -kernel "$elf" > "$work/out" || {
  echo "step-cost: the harness failed:" >&2; cat "$work/out" >&2; exit 1; }
wait "$counter"

# The harness prints "case N steps S refills R wraps W compares C pended P late L services
# V" per case 1..6, and the two priorities first.
mapfile -t cases < <(grep '^case ' "$work/out")
mapfile -t counts < <(grep '^counts ' "$work/counts")
[ "${#cases[@]}" -eq 6 ] && [ "${#counts[@]}" -eq 7 ] || {
  echo "step-cost: expected 6 measured cases and 7 counts:" >&2; cat "$work/out" "$work/counts" >&2; exit 1; }
read -r _ _ lock_level _ dir_level < <(grep '^levels step-lock ' "$work/out") || {
  echo "step-cost: the harness did not print its priority levels:" >&2; cat "$work/out" >&2; exit 1; }
# BASEPRI = L masks priorities L and numerically above; the DIR interrupt's is D.
basepri_masks_dir=$(( lock_level <= dir_level ? 1 : 0 ))

names=("1 joint, 100 kHz" "8 joints in step, 100 kHz" "8 joints, distinct rates 67-100 kHz"
       "1 joint, 1 kHz" "8 joints in step, 1 kHz" "8 joints, distinct rates 0.67-1 kHz")
printf '%-37s %8s %8s %8s %8s %8s   %s\n' "trajectory (10 segments, reversing)" "per step" "start" "refills" "TIM13" "service" "(steps; refills, wraps, alarms, services)"
for i in 0 1 2 3 4 5; do
  read -r _ _ _ steps _ refills _ wraps _ compares _ pended _ _ _ services <<<"${cases[$i]}"
  read -r _ start refill tim13 service <<<"${counts[$((i + 1))]}"
  awk -v n="${names[$i]}" -v s="$steps" -v a="$start" -v r="$refill" -v t="$tim13" -v v="$service" \
      -v rc="$refills" -v w="$wraps" -v al="$((compares + pended))" -v sv="$services" 'BEGIN {
    printf "%-37s %8.1f %8.1f %8.1f %8.1f %8.1f   (%d; %d, %d, %d, %d)\n", n, (a + r + t + v) / s, a / s, r / s, t / s, v / s, s, rc, w, al, sv }'
done
# The longest span per section and trajectory during which the DIR interrupt (TIM13) is
# masked, in instructions and in microseconds at 400 MHz taking one instruction a cycle
# (the M7 may dual-issue; flash and bus waits add cycles: a rough figure until the DWT
# measures it on the board, BOARD.md's bring-up checklist). Goal (issue 20): <= 1 us, so
# that a DIR change waits at most that long. PRIMASK spans always count; BASEPRI spans only
# if the lock's level masks the DIR interrupt's priority. The longest BASEPRI span is shown
# beside them: what the refills and everything below them wait for; then the section's
# longest single run (instructions), which for TIM13 bounds when its last DIR change comes.
echo
if [ "$basepri_masks_dir" -eq 1 ]; then
  echo "longest span with the DIR interrupt masked (PRIMASK, and BASEPRI: the step lock's level $lock_level masks the DIR interrupt's $dir_level):"
else
  echo "longest span with the DIR interrupt masked (PRIMASK only: the step lock's BASEPRI level $lock_level leaves the DIR interrupt's $dir_level running):"
fi
printf '%-37s %-9s %12s %9s   %-28s %9s %9s %9s\n' "trajectory" "section" "instructions" "us@400MHz" "begins in" "BASEPRI" "us@400MHz" "longest"
awk -v names="$(printf '%s|' "${names[@]}")" -v bm="$basepri_masks_dir" '
  BEGIN { split(names, name, "|") }
  /^counts/ { n++ }
  /^mask / && n > 1 {
    d = $3; w = $4
    if (bm && $5 > d) { d = $5; w = $6 }
    us = d / 400
    # (A section inlined into the harness, the positions read, has no run of its own.)
    printf "%-37s %-9s %12d %9.2f   %-28s %9d %9.2f %9s%s\n", name[n - 1], $2, d, us, substr(w, 1, 28), $5, $5 / 400, ($7 > 0 ? $7 : "-"), (us > 1 ? "  (over 1 us)" : "")
  }' "$work/counts"
worst=$(awk -v bm="$basepri_masks_dir" '/^counts/ { n++ } /^mask / && n > 1 { d = $3; if (bm && $5 > d) d = $5; if (d > m) m = d } END { print m + 0 }' "$work/counts")
bworst=$(awk '/^counts/ { n++ } /^mask / && n > 1 && $5 > m { m = $5 } END { print m + 0 }' "$work/counts")
[ "$worst" -gt 0 ] || { echo "step-cost: no masked span measured (the trace found no critical section)" >&2; exit 1; }
dirrun=$(awk '/^counts/ { n++ } /^mask tim13 / && n > 1 && $7 > m { m = $7 } END { print m + 0 }' "$work/counts")
[ "$dirrun" -gt 0 ] || { echo "step-cost: no TIM13 interrupt measured" >&2; exit 1; }
awk -v w="$worst" -v b="$bworst" -v t="$dirrun" 'BEGIN {
  printf "longest with the DIR interrupt masked: %d instructions, %.2f us at 400 MHz (goal <= 1 us)\n", w, w / 400
  printf "longest run of the DIR interrupt itself (TIM13; its last DIR change comes before its end): %d instructions, %.2f us\n", t, t / 400
  printf "longest step lock (BASEPRI) span: %d instructions, %.2f us at 400 MHz\n", b, b / 400 }'

if [ -n "$detail" ]; then
  awk '/^counts/ { n++ } /^fn / && n > 1 { printf "case %d %8d %s\n", n - 1, $2, $3 }' "$work/counts" \
    | sort -k2,2n -k3,3nr | awk '{ k = $2; if (seen[k]++ < 12) print }'
fi
