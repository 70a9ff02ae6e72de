#!/usr/bin/env bash
# Instructions authentication (docs/PROTOCOL.md section 13) adds to one 12-point PENDING on
# the controller, on QEMU's Cortex-M7 (mps2-an500) at the board's code generation (opt-level
# 3, fat LTO, target-cpu=cortex-m7): opening the 1,426-byte envelope (both CRCs), verifying
# its keyed BLAKE2s-128 MAC, and sealing the 11-byte ACK. Counted exactly with
# `-singlestep -d exec,nochain` between the markers auth_cost_on and auth_cost_off (median
# of 3 rounds), then what that allows at 480 MHz.
#
# Needs: qemu-system-arm, the thumbv7em-none-eabihf target. Usage: run.sh
set -euo pipefail

here="$(cd "$(dirname "$0")" && pwd)"
root="$(cd "$here/../.." && pwd)"
cd "$here"

profile_opt_levels() { # file section-prefix
  awk -v p="$2" '/^\[/ { inside = index($0, "[" p) == 1 } inside && /^opt-level/ { print $0 }' "$1"
}
if [ "$(profile_opt_levels "$root/Cargo.toml" "profile.fw" | sort)" != "$(profile_opt_levels Cargo.toml "profile.release" | sort)" ]; then
  echo "auth-cost: Cargo.toml's opt-level differs from the board's [profile.fw]" >&2
  exit 1
fi
command -v qemu-system-arm >/dev/null || { echo "qemu-system-arm missing: apt-get install -y qemu-system-arm" >&2; exit 1; }

export CARGO_TARGET_DIR="${CARGO_TARGET_DIR:-$root/target}/auth-cost"
export RUSTFLAGS="-C link-arg=-Tlink.x -C target-cpu=cortex-m7"
cargo build --quiet --release --target thumbv7em-none-eabihf
elf="$CARGO_TARGET_DIR/thumbv7em-none-eabihf/release/auth-cost"

work="$(mktemp -d)"
trap 'rm -rf "$work"' EXIT
mkfifo "$work/trace"
awk '
  $NF != prev && $NF == "auth_cost_on" { on = 1; n = 0 }
  $NF != prev && $NF == "auth_cost_off" && on { print n; on = 0 }
  on && $NF != "auth_cost_on" { n++ }
  { prev = $NF }' "$work/trace" > "$work/counts" &
counter=$!
timeout 600 qemu-system-arm -M mps2-an500 -nographic -semihosting -singlestep \
    -d exec,nochain -D "$work/trace" -kernel "$elf" > "$work/out" || {
  echo "auth-cost: the harness failed:" >&2; cat "$work/out" >&2; exit 1; }
wait "$counter"
[ "$(grep -c 'verified true' "$work/out")" -eq 3 ] && [ "$(wc -l < "$work/counts")" -eq 3 ] || {
  echo "auth-cost: expected 3 verified rounds:" >&2; cat "$work/out" "$work/counts" >&2; exit 1; }
sort -n "$work/counts" | awk '{ v[NR] = $1 } END {
  m = v[2]
  printf "authentication, 12-point PENDING (CRC + MAC of the 1426-byte envelope, its ACK sealed): %d instructions (%.0f per point; rounds %d..%d)\n", m, m / 12, v[1], v[3]
  printf "at 480 MHz and 1.3 cycles per instruction: %.0f authenticated points/s of CPU for authentication alone\n", 12 * 480e6 / (1.3 * m)
}'
