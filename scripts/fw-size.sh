#!/usr/bin/env bash
# Prints the release firmware's section sizes: text (flash), data (flash + RAM), bss (RAM),
# and fails when the flash image (text + data) is over FW_FLASH_LIMIT bytes (default 96 KiB,
# 98,304 bytes, with defmt at info: issue 9's budget). A big .data means a static with a
# non-zero const initialiser; the script then lists the largest. It also checks the memory
# layout and the largest stack frame. Run after `cargo fw`. Uses llvm-size, llvm-nm and
# llvm-objdump from the pinned toolchain's llvm-tools component.
# Usage: scripts/fw-size.sh [path/to/firmware.elf]
set -euo pipefail
cd "$(dirname "$0")/.."

target_dir="${CARGO_TARGET_DIR:-target}"
elf="${1:-$target_dir/thumbv7em-none-eabihf/fw/firmware}"
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
flash_limit="${FW_FLASH_LIMIT:-98304}"
# llvm-size counts the NOLOAD SRAM1 section (DMA buffers) in bss: AXI SRAM holds the rest.
sram1="$("$size_tool" -A "$elf" | awk '$1 == ".sram1" { print $2 }')"
printf 'flash image %d bytes (text + data) of %d allowed; AXI RAM static %d of 524288 bytes, SRAM1 %d of 131072\n' \
  "$((text + data))" "$flash_limit" "$((data + bss - ${sram1:-0}))" "${sram1:-0}"
# Per-section detail, for finding what grew.
"$size_tool" -A "$elf" | awk 'NR > 2 && $2 > 0 && $1 !~ /^\.debug|^\.comment|^\.ARM|^\.symtab|^\.strtab|^\.shstrtab|^\.defmt|^Total/ {printf "  %-16s %8d @ 0x%08x\n", $1, $2, $3}'

if (( text + data > flash_limit )); then
  echo "fw-size: flash image $((text + data)) bytes is over the $flash_limit-byte budget;" \
    "a big .data means a static with a non-zero const initialiser (make it zero or build it at run time)" >&2
  over_budget=1
fi

# Layout checks: the reset handler zeroes .bss from __sbss to __ebss and copies .data, so both
# must stay inside AXI SRAM; the stack must be DTCM (memory.x). A wrong memory.x fails here
# instead of faulting at reset on the board.
nm_tool="$sysroot/lib/rustlib/$host/bin/llvm-nm"
symbols="$("$nm_tool" "$elf")"
symbol() { awk -v s="$1" '$3 == s { print $1 }' <<<"$symbols" | head -n 1; }
check_range() { # name value low high
  local v=$((16#$2))
  if (( v < $3 || v > $4 )); then
    printf 'fw-size: %s = 0x%x is outside 0x%x..0x%x: check memory.x\n' "$1" "$v" "$3" "$4" >&2
    exit 1
  fi
}
axi_start=$((0x24000000)); axi_end=$((0x24080000))
for s in __sdata __edata __sbss __ebss; do
  value="$(symbol "$s")"
  [ -n "$value" ] || { echo "fw-size: symbol $s missing" >&2; exit 1; }
  check_range "$s" "$value" "$axi_start" "$axi_end"
done
check_range _stack_start "$(symbol _stack_start)" $((0x20020000)) $((0x20020000))
echo "layout ok: .data/.bss in AXI SRAM (ends 0x$(symbol __ebss)), stack top 0x$(symbol _stack_start) (DTCM)"

# Stack check: the stack is 128 KiB of DTCM, and the 300 KB controller must be built in place
# in its static, never on the stack first. Fail if any function reserves a frame over 32 KiB.
objdump_tool="$sysroot/lib/rustlib/$host/bin/llvm-objdump"
largest_frame=0
while read -r hex; do
  (( 16#$hex > largest_frame )) && largest_frame=$((16#$hex))
done < <("$objdump_tool" -d --no-show-raw-insn "$elf" \
  | grep -oE 'sub(\.w|w)?[[:space:]]+sp, (sp, )?#0x[0-9a-f]+' | sed 's/.*#0x//')
largest_frame=${largest_frame:-0}
if (( largest_frame > 32768 )); then
  echo "fw-size: a function reserves a $largest_frame-byte stack frame (over 32 KiB): something big is built on the stack" >&2
  exit 1
fi
echo "stack ok: largest single stack frame $largest_frame bytes (of 131072 DTCM)"
if [ -n "${over_budget:-}" ]; then
  echo "fw-size: largest .data statics (const-initialised, stored in flash):" >&2
  "$nm_tool" --print-size --size-sort --radix=d -C "$elf" | awk '$3 ~ /^[dD]$/' | tail -n 5 \
    | awk '{ printf "  %8d  %s\n", $2, $4 }' >&2
  exit 1
fi
