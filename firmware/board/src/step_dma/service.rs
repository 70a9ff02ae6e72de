//! The step service interrupt: the step path's work that needs the step lock but is
//! started from above it. TIM7's vector (a basic timer this board does not use, so its
//! vector is free: only ever pended by software), at the refills' priority P2.
//!
//! What pends it:
//! - the step clock (TIM13, P1), when the run's end it was given has come: the end needs
//!   the producer, behind the step lock, which TIM13 must never take (`lock.rs`);
//! - the wired e-stop input (EXTI0, P0), after it forced every STEP output off: the
//!   backend's halt (positions unwound, no run until the input closes) and the trajectory
//!   task's wake-up (`crate::estop::service`);
//! - the limit and home switches' EXTI handlers (P0): each edge fed to the switch line
//!   with the joint's count, a limit trip's halt (`crate::switches::service`).

use embassy_stm32::interrupt::InterruptExt;
use embassy_stm32::{interrupt, pac};

use super::STEP;
use super::lock::STEP_LOCK_PRIORITY;

/// The service's interrupt (pend it with `NVIC::pend`).
pub const SERVICE_IRQ: pac::Interrupt = pac::Interrupt::TIM7;

/// Sets the service interrupt's priority (the step lock's level: it takes the lock) and
/// enables it.
pub(super) fn init() {
    interrupt::TIM7.set_priority(STEP_LOCK_PRIORITY);
    // SAFETY: the handler takes the step lock (at its level) and the e-stop line's
    // state; nothing else enables TIM7.
    unsafe { interrupt::TIM7.enable() };
}

#[interrupt]
fn TIM7() {
    crate::estop::service();
    #[cfg(feature = "switch-inputs")]
    crate::switches::service();
    STEP.on_interrupt(&crate::BUS.step_progress, |steps| {
        ((), steps.on_service(crate::step_timer::now_tick()))
    });
}
