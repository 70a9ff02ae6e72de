//! The wired e-stop input (issue 18, part 3): PC0 (Zio A1), a normally-closed contact to
//! GND, read with the internal pull-up, so that a pressed button *and* a broken wire read
//! high: open. EXTI line 0 interrupts on both edges at P0, above every other interrupt
//! (main.rs's priority table), and its handler stops every STEP output itself: the step
//! backend's emergency stop ([`arm_core::EStopLine::edge`] -> `StepShared::halt` ->
//! `BoardSteps::stop` -> [`crate::step_dma::stop_all_step_outputs`]: every joint timer's
//! output forced inactive first, then counters and streams stopped), with no run allowed
//! to start until the input closes. Then it wakes the trajectory task, which puts the
//! controller in STOPPED and latches it (RUNING and RETURN refused until the input is
//! closed and a host sends ESTOP_RESET). docs/BOARD.md, "Wired e-stop input", has the path
//! from pin to STEP low with its instruction count and the worst case.

use arm_core::EStopLine;
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::{Peri, interrupt, pac, peripherals};

use crate::step_dma::STEP;
use crate::step_timer::STEP_TIMER;

/// The input's state, shared by [`EXTI0`] and the trajectory task.
pub static LINE: EStopLine = EStopLine::new();

/// The input's pin number on GPIOC (and so its EXTI line).
const PIN: usize = 0;

/// Whether the input reads open (high: the contact no longer pulls it to GND).
fn is_open() -> bool {
    pac::GPIOC.idr().read().idr(PIN) == pac::gpio::vals::Idr::HIGH
}

/// Makes PC0 an input with its pull-up, routes it to EXTI line 0 on both edges and enables
/// the interrupt at P0. Call after the step outputs are set up (`start_steps`) and the bus
/// is built; an input already open at boot latches at once.
pub fn start(_pin: Peri<'static, peripherals::PC0>) {
    let port = pac::GPIOC;
    port.pupdr()
        .modify(|w| w.set_pupdr(PIN, pac::gpio::vals::Pupdr::PULL_UP));
    port.moder()
        .modify(|w| w.set_moder(PIN, pac::gpio::vals::Moder::INPUT));
    pac::RCC.apb4enr().modify(|w| w.set_syscfgen(true));
    // EXTICR1's field 0: port C is 2.
    pac::SYSCFG.exticr(0).modify(|w| w.set_exti(PIN, 2));
    let exti = pac::EXTI;
    exti.rtsr(0).modify(|w| w.set_line(PIN, true));
    exti.ftsr(0).modify(|w| w.set_line(PIN, true));
    exti.imr(0).modify(|w| w.set_line(PIN, true));
    interrupt::EXTI0.set_priority(Priority::P0);
    // SAFETY: the handler touches EXTI's pending bit, GPIOC's input and STEP, LINE and the
    // bus's signal (critical sections).
    unsafe { interrupt::EXTI0.enable() };
    // An edge before the interrupt was enabled is pending and runs the handler; a level
    // that did not change is read here.
    if is_open() {
        interrupt::EXTI0.pend();
    }
}

/// The input's edge: STEP low (the backend's stop) first, then the trajectory task woken.
#[interrupt]
fn EXTI0() {
    // rc_w1: writing 1 clears the pending bit. Cleared before the pin is read, so an edge
    // after the read pends the interrupt again.
    pac::EXTI.pr(0).write(|w| w.set_line(PIN, true));
    LINE.edge(is_open(), &STEP, &STEP_TIMER, &crate::BUS.step_progress);
}
