//! Small `memcpy`, `memmove`, `memset`, `memcmp` (and the ARM EABI `__aeabi_*` entry
//! points) for both boards, in place of compiler-builtins' speed-tuned ones, which take
//! about 3.4 KiB of the NUCLEO image's flash (`memmove` alone 1.5 KiB). These
//! copy a word at a time when both pointers are word-aligned and a byte at a time
//! otherwise: at 400 MHz a full Ethernet frame (1.5 KiB) is copied in a few microseconds.
//! The step path's cost is measured apart (scripts/step-cost builds arm-step on its own).
//! The QEMU board runs the same code under the system tests, and `runtime_check.rs` checks
//! every alignment, length and overlap against byte-by-byte models on the emulated
//! Cortex-M7 (tests/tests/qemu.rs).
//!
//! compiler-builtins defines its versions as weak symbols so that a C library (or this)
//! can replace them. They are assembly, not Rust: LLVM turns a Rust copy loop back into a
//! call to `memcpy`, which would call itself. Each function is in its own section, so the
//! linker drops the ones nothing calls.
//!
//! Contracts (C and the ARM run-time ABI): `memcpy(dst, src, n) -> dst` (no overlap),
//! `memmove(dst, src, n) -> dst` (any overlap), `memset(dst, c, n) -> dst`,
//! `memcmp(a, b, n) -> int` (sign of the first differing byte pair, unsigned bytes);
//! `__aeabi_memcpy*`/`__aeabi_memmove*(dst, src, n)`, `__aeabi_memset*(dst, n, c)` (note
//! the order) and `__aeabi_memclr*(dst, n)` return nothing; the `4`/`8` variants promise
//! aligned pointers, which the generic code handles anyway. Only r0-r3, r12 and the flags
//! are used (caller-saved under the AAPCS).

core::arch::global_asm!(
    ".syntax unified",
    ".thumb",
    // memcpy: forward copy. r0 = dst, r1 = src, r2 = n; returns dst.
    ".pushsection .text.memcpy,\"ax\",%progbits",
    ".global memcpy",
    ".global __aeabi_memcpy",
    ".global __aeabi_memcpy4",
    ".global __aeabi_memcpy8",
    ".type memcpy,%function",
    ".type __aeabi_memcpy,%function",
    ".type __aeabi_memcpy4,%function",
    ".type __aeabi_memcpy8,%function",
    ".thumb_func",
    "memcpy:",
    ".thumb_func",
    "__aeabi_memcpy:",
    ".thumb_func",
    "__aeabi_memcpy4:",
    ".thumb_func",
    "__aeabi_memcpy8:",
    "    mov r12, r0",
    // Words while both pointers are aligned and 4 or more bytes are left.
    "    orr r3, r0, r1",
    "    lsls r3, r3, #30",
    "    bne 2f",
    "1:  subs r2, r2, #4",
    "    bcc 3f",
    "    ldr r3, [r1], #4",
    "    str r3, [r0], #4",
    "    b 1b",
    "3:  adds r2, r2, #4",
    // Then (or from the start, if unaligned) bytes.
    "2:  cbz r2, 4f",
    "    ldrb r3, [r1], #1",
    "    strb r3, [r0], #1",
    "    subs r2, r2, #1",
    "    b 2b",
    "4:  mov r0, r12",
    "    bx lr",
    ".size memcpy, . - memcpy",
    // memmove: forward (memcpy) unless dst lies inside [src, src + n), then backward.
    ".section .text.memmove,\"ax\",%progbits",
    ".global memmove",
    ".global __aeabi_memmove",
    ".global __aeabi_memmove4",
    ".global __aeabi_memmove8",
    ".type memmove,%function",
    ".type __aeabi_memmove,%function",
    ".type __aeabi_memmove4,%function",
    ".type __aeabi_memmove8,%function",
    ".thumb_func",
    "memmove:",
    ".thumb_func",
    "__aeabi_memmove:",
    ".thumb_func",
    "__aeabi_memmove4:",
    ".thumb_func",
    "__aeabi_memmove8:",
    // dst - src (unsigned) >= n: no destination byte precedes its source byte being read.
    "    subs r3, r0, r1",
    "    cmp r3, r2",
    "    bhs memcpy",
    "    mov r12, r0",
    "    add r0, r0, r2",
    "    add r1, r1, r2",
    // Backward: words when both ends and the length are aligned, else bytes.
    "    orr r3, r0, r1",
    "    orr r3, r3, r2",
    "    lsls r3, r3, #30",
    "    bne 2f",
    "1:  cbz r2, 4f",
    "    ldr r3, [r1, #-4]!",
    "    str r3, [r0, #-4]!",
    "    subs r2, r2, #4",
    "    b 1b",
    "2:  cbz r2, 4f",
    "    ldrb r3, [r1, #-1]!",
    "    strb r3, [r0, #-1]!",
    "    subs r2, r2, #1",
    "    b 2b",
    "4:  mov r0, r12",
    "    bx lr",
    ".size memmove, . - memmove",
    // memset: r0 = dst, r1 = byte, r2 = n; returns dst. The EABI entry points take
    // (dst, n, byte) or (dst, n) and join it with the arguments in memset's order.
    ".section .text.memset,\"ax\",%progbits",
    ".global memset",
    ".global __aeabi_memset",
    ".global __aeabi_memset4",
    ".global __aeabi_memset8",
    ".global __aeabi_memclr",
    ".global __aeabi_memclr4",
    ".global __aeabi_memclr8",
    ".type memset,%function",
    ".type __aeabi_memset,%function",
    ".type __aeabi_memset4,%function",
    ".type __aeabi_memset8,%function",
    ".type __aeabi_memclr,%function",
    ".type __aeabi_memclr4,%function",
    ".type __aeabi_memclr8,%function",
    ".thumb_func",
    "__aeabi_memclr:",
    ".thumb_func",
    "__aeabi_memclr4:",
    ".thumb_func",
    "__aeabi_memclr8:",
    "    movs r2, #0",
    ".thumb_func",
    "__aeabi_memset:",
    ".thumb_func",
    "__aeabi_memset4:",
    ".thumb_func",
    "__aeabi_memset8:",
    // (dst, n, c) -> (dst, c, n)
    "    mov r3, r1",
    "    mov r1, r2",
    "    mov r2, r3",
    ".thumb_func",
    "memset:",
    "    mov r12, r0",
    // The byte in all four lanes of r1.
    "    uxtb r1, r1",
    "    orr r1, r1, r1, lsl #8",
    "    orr r1, r1, r1, lsl #16",
    // Bytes up to a word boundary, then words, then the tail bytes.
    "1:  lsls r3, r0, #30",
    "    beq 2f",
    "    cbz r2, 4f",
    "    strb r1, [r0], #1",
    "    subs r2, r2, #1",
    "    b 1b",
    "2:  subs r2, r2, #4",
    "    bcc 3f",
    "    str r1, [r0], #4",
    "    b 2b",
    "3:  adds r2, r2, #4",
    "5:  cbz r2, 4f",
    "    strb r1, [r0], #1",
    "    subs r2, r2, #1",
    "    b 5b",
    "4:  mov r0, r12",
    "    bx lr",
    ".size memset, . - memset",
    // memcmp: r0 = a, r1 = b, r2 = n; returns the difference of the first unequal bytes
    // (as unsigned), 0 if none.
    ".section .text.memcmp,\"ax\",%progbits",
    ".global memcmp",
    ".type memcmp,%function",
    ".thumb_func",
    "memcmp:",
    "1:  cbz r2, 2f",
    "    ldrb r3, [r0], #1",
    "    ldrb r12, [r1], #1",
    "    subs r3, r3, r12",
    "    bne 3f",
    "    subs r2, r2, #1",
    "    b 1b",
    "2:  movs r0, #0",
    "    bx lr",
    "3:  mov r0, r3",
    "    bx lr",
    ".size memcmp, . - memcmp",
    // Back to the section the assembler was in.
    ".popsection",
);
