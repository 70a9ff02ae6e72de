//! The board's own timing counters (issue 34 part C): what the emulators cannot measure,
//! counted by the firmware on the chip and told by the DIAG report (`armctl diag`;
//! docs/PROTOCOL.md "DIAG"). arm-core's `diag` structs do the arithmetic (host-tested);
//! this file stamps them:
//!
//! - **Masked spans.** This board's critical-section implementation (it replaces
//!   `cortex-m`'s single-core one, with the same PRIMASK save and restore) stamps DWT
//!   CYCCNT when the outermost section opens and closes, with the return address into the
//!   code that opened it (`_critical_section_1_0_acquire` is kept out of line for that:
//!   its LR on entry is the caller's). Cost: a call, two CYCCNT loads and a few stores
//!   per section, all inside the span it measures (so counted in it).
//! - **DIR lateness.** The step clock's interrupt (`step_timer.rs`), at each DIR write:
//!   TIM13's counter against the tick the change was due ([`dir_written`]).
//! - **DMA slack.** Each refill interrupt (`step_dma/refill.rs`), before it refills: its
//!   timer's counter against the playing period's reload ([`refill_looked`]).
//!
//! Each counter is written from one context only, so none needs a lock of its own: the
//! spans with every interrupt masked, DIR lateness from TIM13's interrupt (P1), DMA slack
//! from the refills (P2, one level: they never preempt each other). [`read`] copies them
//! in a critical section, which none of those writers can be inside of.

use core::arch::asm;
use core::cell::UnsafeCell;

use arm_core::diag::{DirLateness, DmaSlack, MaskedSpans};
use cortex_m::peripheral::{DCB, DWT};

/// The CPU clock CYCCNT counts (`clocks.rs`: PLL1P, whichever oscillator feeds it).
pub const CPU_HZ: u32 = 400_000_000;

/// A counter written from one context only (module header).
struct OneWriter<T>(UnsafeCell<T>);

// SAFETY: each `OneWriter` is written from one context only, which nothing that reads or
// writes it can preempt mid-access: see the module header and each static.
unsafe impl<T: Send> Sync for OneWriter<T> {}

impl<T: Copy> OneWriter<T> {
    /// # Safety
    /// The caller is the counter's only writer (its static says which) and no reader can
    /// run until `f` returns.
    unsafe fn update(&self, f: impl FnOnce(&mut T)) {
        // SAFETY: see the function's contract.
        f(unsafe { &mut *self.0.get() })
    }

    /// # Safety
    /// The caller is in a critical section (no writer runs meanwhile).
    unsafe fn get(&self) -> T {
        // SAFETY: see the function's contract.
        unsafe { *self.0.get() }
    }
}

/// Written with every interrupt masked (the critical section's own open and close).
static SPANS: OneWriter<MaskedSpans> = OneWriter(UnsafeCell::new(MaskedSpans::NEW));
/// Written by TIM13's interrupt (P1) only.
static DIR: OneWriter<DirLateness> = OneWriter(UnsafeCell::new(DirLateness::NEW));
/// Written by the DMA2 stream interrupts (P2, one level) only.
static DMA: OneWriter<DmaSlack> = OneWriter(UnsafeCell::new(DmaSlack::NEW));

/// Starts the cycle counter (the trace block on, DWT unlocked: the H7's DWT is locked
/// after a power cycle) and gives the bus the report's source. Spans before it count 0
/// cycles.
pub fn start(dcb: &mut DCB, dwt: &mut DWT) {
    dcb.enable_trace();
    DWT::unlock();
    dwt.enable_cycle_counter();
    crate::BUS.set_diag_source(read);
}

/// The DIAG report's counters (arm-core's `Bus::diag` calls it, in thread mode).
fn read() -> protocol::Diag {
    critical_section::with(|_| {
        // SAFETY: in a critical section: no writer runs.
        let (spans, dir, dma) = unsafe { (SPANS.get(), DIR.get(), DMA.get()) };
        arm_core::diag::report(spans, dir, dma, CPU_HZ, crate::step_dma::STEP_TIMER_HZ)
    })
}

/// A DIR line was written by TIM13's interrupt with its counter at `counter`, for a
/// change due at step clock tick `due`. From TIM13's interrupt only.
pub fn dir_written(counter: u16, due: u64) {
    // SAFETY: TIM13's interrupt is DIR's only writer; readers run in thread mode under a
    // critical section, which cannot preempt it.
    unsafe { DIR.update(|d| d.written(counter, due)) };
}

/// A refill interrupt looked at its timer: the playing period's `reload` and the
/// `counter`. From the DMA2 stream interrupts only.
pub fn refill_looked(reload: u32, counter: u32) {
    // SAFETY: the stream interrupts (one priority: none preempts another) are DMA's only
    // writers; readers run in thread mode under a critical section.
    unsafe { DMA.update(|d| d.sampled(reload, counter)) };
}

/// PRIMASK bit 0: interrupts masked.
const PRIMASK_MASKED: u32 = 1;

/// The critical section's entry (the `critical-section` crate's symbol, as its
/// `set_impl!` would make it, but kept out of line: its LR on entry is the return address
/// into the code that opened the section). Returns the PRIMASK it found, as `cortex-m`'s
/// implementation does.
///
/// # Safety
/// The `critical-section` crate's contract: paired with [`_critical_section_1_0_release`]
/// given what this returned.
#[unsafe(no_mangle)]
#[inline(never)]
unsafe fn _critical_section_1_0_acquire() -> critical_section::RawRestoreState {
    let opener: u32;
    // SAFETY: reads LR, nothing else; first, before any call could change it.
    unsafe { asm!("mov {}, lr", out(reg) opener, options(nomem, nostack, preserves_flags)) };
    let restore = cortex_m::register::primask::read_raw();
    cortex_m::interrupt::disable();
    if restore & PRIMASK_MASKED == 0 {
        // SAFETY: every interrupt is masked: this is SPANS' only access now.
        unsafe { SPANS.update(|s| s.open(DWT::cycle_count(), opener)) };
    }
    restore
}

/// The critical section's exit: closes the span if it restores an unmasked PRIMASK.
///
/// # Safety
/// The `critical-section` crate's contract: `restore` is what the matching
/// [`_critical_section_1_0_acquire`] returned.
#[unsafe(no_mangle)]
unsafe fn _critical_section_1_0_release(restore: critical_section::RawRestoreState) {
    if restore & PRIMASK_MASKED == 0 {
        // SAFETY: every interrupt is still masked: this is SPANS' only access now.
        unsafe { SPANS.update(|s| s.close(DWT::cycle_count())) };
    }
    // SAFETY: restores the PRIMASK the matching acquire found.
    unsafe { cortex_m::register::primask::write_raw(restore) };
}
