#!/usr/bin/env bash
# Prints the release firmware's section sizes: text (flash), data (flash + RAM), bss (RAM).
# Run after `cargo fw`. Uses llvm-size from the pinned toolchain's llvm-tools component.
# Usage: scripts/fw-size.sh [path/to/firmware.elf]
set -euo pipefail
cd "$(dirname "$0")/.."

target_dir="${CARGO_TARGET_DIR:-target}"
elf="${1:-$target_dir/thumbv7em-none-eabihf/release/firmware}"
if [ ! -f "$elf" ]; then
  echo "fw-size: $elf not found; build it with 'cargo fw' first" >&2
  exit 1
fi

sysroot="$(rustc --print sysroot)"
host="$(rustc -vV | sed -n 's/^host: //p')"
size_tool="$sysroot/lib/rustlib/$host/bin/llvm-size"
if [ ! -x "$size_tool" ]; then
  echo "fw-size: $size_tool missing; run 'rustup component add llvm-tools'" >&2
  exit 1
fi

# Berkeley format: text data bss dec hex filename.
read -r text data bss _ < <("$size_tool" -B "$elf" | sed -n 2p)
printf 'firmware: %s\n' "$elf"
printf 'text %8d bytes  (flash: code, constants, vector table)\n' "$text"
printf 'data %8d bytes  (flash image copied to RAM at boot)\n' "$data"
printf 'bss  %8d bytes  (RAM zeroed at boot)\n' "$bss"
printf 'flash used %d of 2097152 bytes, AXI RAM static %d of 524288 bytes\n' \
  "$((text + data))" "$((data + bss))"
# Per-section detail, for finding what grew.
"$size_tool" -A "$elf" | awk 'NR > 2 && $2 > 0 && $1 !~ /^\.debug|^\.comment|^\.ARM|^\.symtab|^\.strtab|^\.shstrtab|^\.defmt|^Total/ {printf "  %-16s %8d @ 0x%08x\n", $1, $2, $3}'
