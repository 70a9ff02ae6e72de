//! A small `__aeabi_uldivmod` (u64 division and remainder, what `/` and `%` on `u64` call on
//! ARMv7-M) for both boards, in place of compiler-builtins' speed-tuned one, which takes
//! 932 bytes of the NUCLEO image's flash (its `u64_div_rem` alone 864); this is 140.
//!
//! When both operands fit in 32 bits (most calls), this is the hardware `udiv`. Otherwise
//! it is a shift-and-subtract division over the quotient's bits only (the divisor is first
//! aligned with the dividend's top bit): about 1,200 cycles at worst (63 shift-and-subtract
//! steps), about 3 us at 400 MHz. The u64 divisions here are off the step path's per-pulse work: arm-step
//! divides in u32 whenever a segment's figures fit (its `begin_segment`), and the others
//! are in tasks (time conversions, encoder and trajectory arithmetic).
//!
//! compiler-builtins defines its version as a weak symbol, so this one replaces it; like
//! `mem.rs`, it is assembly so that LLVM cannot turn it back into a call to itself.
//!
//! ARM run-time ABI: numerator in r0 (low) r1 (high), denominator in r2, r3; returns the
//! quotient in r0, r1 and the remainder in r2, r3. Rust checks for a zero divisor before
//! it divides (a panic); given one anyway, this returns without trapping. Uses r0-r3, r12
//! and the flags, and saves r4-r7.
//!
//! `runtime_check.rs` checks it against a bit-by-bit model division on the emulated
//! Cortex-M7 (tests/tests/qemu.rs): edge values and pseudo-random operands of every bit
//! length.

core::arch::global_asm!(
    ".syntax unified",
    ".thumb",
    ".pushsection .text.__aeabi_uldivmod,\"ax\",%progbits",
    ".global __aeabi_uldivmod",
    ".type __aeabi_uldivmod,%function",
    ".thumb_func",
    "__aeabi_uldivmod:",
    "    orrs r12, r1, r3",
    "    bne 1f",
    // 32 by 32 bits: q = n / d, r = n - q * d.
    "    udiv r12, r0, r2",
    "    mls r2, r12, r2, r0",
    "    mov r0, r12",
    "    movs r1, #0",
    "    movs r3, #0",
    "    bx lr",
    "1:  push {{r4, r5, r6, r7}}",
    // n < d: q = 0, r = n.
    "    subs r12, r0, r2",
    "    sbcs r12, r1, r3",
    "    bcc 6f",
    // r6 = leading zeros of d (64 bits), r7 = those of n; n >= d so r6 >= r7.
    "    clz r6, r3",
    "    cmp r3, #0",
    "    itt eq",
    "    clzeq r6, r2",
    "    addeq r6, r6, #32",
    "    clz r7, r1",
    "    cmp r1, #0",
    "    itt eq",
    "    clzeq r7, r0",
    "    addeq r7, r7, #32",
    // r6 = s = quotient bits - 1; d <<= s (its top bit then is n's).
    "    subs r6, r6, r7",
    "    mov r7, r6",
    "2:  cbz r7, 3f",
    "    lsls r2, r2, #1",
    "    adc r3, r3, r3",
    "    subs r7, r7, #1",
    "    b 2b",
    "3:  movs r4, #0",
    "    movs r5, #0",
    "    adds r6, r6, #1",
    // s + 1 times: q <<= 1; if n >= d { n -= d; q |= 1 }; d >>= 1.
    "4:  lsls r4, r4, #1",
    "    adc r5, r5, r5",
    "    subs r7, r0, r2",
    "    sbcs r12, r1, r3",
    "    bcc 5f",
    "    mov r0, r7",
    "    mov r1, r12",
    "    orr r4, r4, #1",
    "5:  lsrs r3, r3, #1",
    "    rrx r2, r2",
    "    subs r6, r6, #1",
    "    bne 4b",
    // q = r4:r5, r = what is left of n.
    "    mov r2, r0",
    "    mov r3, r1",
    "    mov r0, r4",
    "    mov r1, r5",
    "    pop {{r4, r5, r6, r7}}",
    "    bx lr",
    "6:  mov r2, r0",
    "    mov r3, r1",
    "    movs r0, #0",
    "    movs r1, #0",
    "    pop {{r4, r5, r6, r7}}",
    "    bx lr",
    ".size __aeabi_uldivmod, . - __aeabi_uldivmod",
    // Back to the section the assembler was in.
    ".popsection",
);
