//! [`StepLock`]: the step path's lock, a BASEPRI mask at the refills' priority instead of
//! a critical section (issue 20, "DIR never late, by construction").
//!
//! `cortex-m`'s critical sections set PRIMASK: every interrupt waits, the step clock's DIR
//! changes (TIM13, [`DIR_PRIORITY`]) and the wired e-stop input (EXTI0, P0) too. The step
//! path's sections are long (a refill of 8 joints at 1 kHz, 15 us; a run's start, up to
//! 189 us: `scripts/step-cost`), so a DIR change could come late and a reversal's first
//! pulse in the wrong direction. This lock raises BASEPRI to [`STEP_LOCK_PRIORITY`]
//! (P2, the DMA refills' and the step service's level): it holds off exactly the code that
//! takes it (the refills, the service, thread mode, and the drivers and embassy-time
//! below) and leaves P0 and P1 running.
//!
//! The price: nothing above P2 may take it (it would not exclude the holder it preempted:
//! a `RefCell` borrowed twice). So the DIR interrupt reads its changes from lock-free
//! queues (`super::DIRS`) and hands the run's end to the service interrupt, and the e-stop
//! input stops the outputs with register writes alone (`super::kill_step_outputs`) and
//! leaves the bookkeeping to the service interrupt (`super::service`). In debug builds
//! every lock checks the priority it is taken at.

use core::sync::atomic::{Ordering, compiler_fence};

use embassy_stm32::interrupt::Priority;
use embassy_sync::blocking_mutex::raw::RawMutex;

/// The DIR changes' interrupt (the step clock, TIM13): above the step lock, so that no
/// step-path section holds it off.
pub const DIR_PRIORITY: Priority = Priority::P1;

/// The step lock's level: the refills' and the service's priority. Interrupts at this
/// priority or below (numerically greater or equal) wait while it is held.
pub const STEP_LOCK_PRIORITY: Priority = Priority::P2;

const _: () = assert!(
    (DIR_PRIORITY as u8) < (STEP_LOCK_PRIORITY as u8),
    "the DIR interrupt must stay above the step lock"
);

/// The step path's raw mutex (see the module header). Sound only while nothing at a
/// priority above [`STEP_LOCK_PRIORITY`] takes it: TIM13 and EXTI0 never touch `STEP`.
pub struct StepLock(());

// SAFETY: mutual exclusion between every context that takes it: thread mode and
// interrupts at P2 or below. While one holds it, BASEPRI = P2 masks every other such
// context on this single core, and a P2 handler that takes it already runs at P2 (no
// other P2 handler can preempt it). Contexts above P2 never take it (module header; checked
// in debug builds). The compiler barriers keep the protected accesses inside.
unsafe impl RawMutex for StepLock {
    const INIT: Self = StepLock(());

    fn lock<R>(&self, f: impl FnOnce() -> R) -> R {
        #[cfg(debug_assertions)]
        check_caller_priority();
        let old = cortex_m::register::basepri::read();
        // BASEPRI_MAX only ever raises the mask: taken inside a section that masks more
        // already, it leaves that mask alone.
        cortex_m::register::basepri_max::write(STEP_LOCK_PRIORITY as u8);
        compiler_fence(Ordering::SeqCst);
        let r = f();
        compiler_fence(Ordering::SeqCst);
        // SAFETY: restores the mask of the caller (never lowers it below that).
        unsafe { cortex_m::register::basepri::write(old) };
        r
    }
}

/// Debug builds: panics if the lock is taken by an interrupt above the step lock's level.
#[cfg(debug_assertions)]
fn check_caller_priority() {
    use cortex_m::peripheral::scb::VectActive;
    if let VectActive::Interrupt { irqn } = cortex_m::peripheral::SCB::vect_active() {
        // SAFETY: reading a priority register.
        let priority = unsafe { (*cortex_m::peripheral::NVIC::PTR).ipr[usize::from(irqn)].read() };
        assert!(
            priority >= STEP_LOCK_PRIORITY as u8,
            "step lock taken above its level"
        );
    }
}
