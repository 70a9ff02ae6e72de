//! The first instructions after reset (cortex-m-rt's `__pre_init`, before RAM is
//! initialised, so assembly: no Rust may run yet). Two jobs that cannot wait for `main`:
//!
//! - **PA15 low.** Joint 0's STEP (PA15) resets as JTDI with the internal pull-up: high
//!   until the firmware takes it, one rising edge, one step, at every reset. Here it becomes
//!   a low output with the pull-down within microseconds of reset, long before `main`
//!   gives it to TIM2. The edge during reset itself only a resistor can prevent: fit the
//!   4.7 kOhm pull-down docs/BOARD.md lists (against the ~40 kOhm pull-up: 0.35 V, well
//!   under V_IL).
//! - **defmt's RTT block in SRAM1.** memory.x puts the RTT control block in SRAM1
//!   (non-cacheable: the probe and the CPU see each other's pointers, `memory.rs`); its
//!   initial value is in flash at `__sirtt` and is copied to `__srtt..__ertt` before
//!   anything can log. SRAM1's clock (RCC_AHB2ENR.SRAM1EN) is switched on first.
//!
//! Registers (RM0433): RCC at 0x5802_4400 (AHB2ENR +0xDC bit 29 SRAM1EN, AHB4ENR +0xE0
//! bit 0 GPIOAEN); GPIOA at 0x5802_0000 (MODER +0x00, PUPDR +0x0C, BSRR +0x18). Each clock
//! enable is read back (and a DSB) before the peripheral is touched.

core::arch::global_asm!(
    ".section .text.__pre_init,\"ax\",%progbits",
    ".global __pre_init",
    ".type __pre_init,%function",
    ".thumb_func",
    "__pre_init:",
    // GPIOA: clock on.
    "ldr r0, =0x580244E0",
    "ldr r1, [r0]",
    "orr r1, r1, #1",
    "str r1, [r0]",
    "ldr r1, [r0]",
    "dsb",
    // PA15: output data low (BSRR.BR15), pull-down (PUPDR15 = 0b10), output (MODER15 = 0b01).
    "ldr r0, =0x58020000",
    "mov r1, #0x80000000",
    "str r1, [r0, #0x18]",
    "ldr r1, [r0, #0x0C]",
    "bic r1, r1, #0xC0000000",
    "orr r1, r1, #0x80000000",
    "str r1, [r0, #0x0C]",
    "ldr r1, [r0]",
    "bic r1, r1, #0xC0000000",
    "orr r1, r1, #0x40000000",
    "str r1, [r0]",
    // SRAM1: clock on.
    "ldr r0, =0x580244DC",
    "ldr r1, [r0]",
    "orr r1, r1, #0x20000000",
    "str r1, [r0]",
    "ldr r1, [r0]",
    "dsb",
    // RTT control block: flash image to SRAM1, a word at a time.
    "ldr r0, =__srtt",
    "ldr r1, =__ertt",
    "ldr r2, =__sirtt",
    "1:",
    "cmp r0, r1",
    "bhs 2f",
    "ldr r3, [r2], #4",
    "str r3, [r0], #4",
    "b 1b",
    "2:",
    "bx lr",
    ".ltorg",
    ".size __pre_init, . - __pre_init",
);
