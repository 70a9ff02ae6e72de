#!/usr/bin/env bash
# Reports the release firmware's section sizes: text (flash), data (flash + RAM), bss (RAM),
# the flash image (text + data, of the 2 MiB part: a report, no budget since issue 20) and
# the largest .data statics (a big .data means a static with a non-zero const initialiser,
# copied from flash at boot). It checks the memory layout and the largest stack frame.
# Run after `cargo fw`. Uses llvm-size, llvm-nm and llvm-objdump from the pinned
# toolchain's llvm-tools component, and fails (never prints a zero) when one is missing or
# reads nothing from the ELF.
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
tool() { # name: the llvm-tools binary, or fail
  local path="$sysroot/lib/rustlib/$host/bin/$1"
  if [ ! -x "$path" ]; then
    echo "fw-size: $path missing; run 'rustup component add llvm-tools'" >&2
    exit 1
  fi
  echo "$path"
}
size_tool="$(tool llvm-size)"
nm_tool="$(tool llvm-nm)"
objdump_tool="$(tool llvm-objdump)"

# Berkeley format: text data bss dec hex filename.
read -r text data bss _ < <("$size_tool" -B "$elf" | sed -n 2p)
if ! [[ "${text:-}" =~ ^[0-9]+$ ]] || (( text == 0 )); then
  echo "fw-size: $size_tool read no code size from $elf" >&2
  exit 1
fi
printf 'firmware: %s\n' "$elf"
printf 'text %8d bytes  (flash: code, constants, vector table)\n' "$text"
printf 'data %8d bytes  (flash image copied to RAM at boot)\n' "$data"
printf 'bss  %8d bytes  (RAM zeroed at boot)\n' "$bss"
# llvm-size counts the NOLOAD SRAM1 and SRAM2 sections (DMA buffers; SRAM2: the step
# streams', issue 34) in bss: AXI SRAM holds the rest.
sram1="$("$size_tool" -A "$elf" | awk '$1 == ".sram1" { print $2 }')"
sram2="$("$size_tool" -A "$elf" | awk '$1 == ".sram2" { print $2 }')"
printf 'flash image %d bytes (text + data) of 2097152; AXI RAM static %d of 524288 bytes, SRAM1 %d of 131072, SRAM2 %d of 131072\n' \
  "$((text + data))" "$((data + bss - ${sram1:-0} - ${sram2:-0}))" "${sram1:-0}" "${sram2:-0}"
# Per-section detail, for finding what grew.
"$size_tool" -A "$elf" | awk 'NR > 2 && $2 > 0 && $1 !~ /^\.debug|^\.comment|^\.ARM|^\.symtab|^\.strtab|^\.shstrtab|^\.defmt|^Total/ {printf "  %-16s %8d @ 0x%08x\n", $1, $2, $3}'

# Layout checks: the reset handler zeroes .bss from __sbss to __ebss and copies .data, so both
# must stay inside AXI SRAM; the stack must be DTCM (memory.x). A wrong memory.x fails here
# instead of faulting at reset on the board.
symbols="$("$nm_tool" "$elf")"
[ -n "$symbols" ] || { echo "fw-size: $nm_tool listed no symbols of $elf" >&2; exit 1; }
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
# A disassembler that cannot read the ELF (an older LLVM printed nothing, and this said
# "largest stack frame 0 bytes") fails here instead.
disassembly="$("$objdump_tool" -d --no-show-raw-insn "$elf")" || {
  echo "fw-size: $objdump_tool could not disassemble $elf" >&2; exit 1; }
frames="$(grep -oE 'sub(\.w|w)?[[:space:]]+sp, (sp, )?#0x[0-9a-f]+' <<<"$disassembly" | sed 's/.*#0x//' || true)"
if [ -z "$frames" ]; then
  echo "fw-size: no stack frame found in $objdump_tool's disassembly of $elf (does it know thumbv7em?)" >&2
  exit 1
fi
largest_frame=0
while read -r hex; do
  (( 16#$hex > largest_frame )) && largest_frame=$((16#$hex))
done <<<"$frames"
if (( largest_frame > 32768 )); then
  echo "fw-size: a function reserves a $largest_frame-byte stack frame (over 32 KiB): something big is built on the stack" >&2
  exit 1
fi
echo "stack ok: largest single stack frame $largest_frame bytes (of 131072 DTCM)"
echo "largest .data statics (const-initialised, copied from flash at boot):"
"$nm_tool" --print-size --size-sort --radix=d -C "$elf" | awk '$3 ~ /^[dD]$/' | tail -n 5 \
  | awk '{ printf "  %8d  %s\n", $2, $4 }'
