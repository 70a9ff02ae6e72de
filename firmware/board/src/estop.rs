//! The wired e-stop input (issue 18, part 3): PC0 (Zio A1), a normally-closed contact to
//! GND, read with the internal pull-up, so that a pressed button *and* a broken wire read
//! high: open. EXTI line 0 interrupts on both edges at P0, above every other interrupt
//! (main.rs's priority table), and its handler stops every STEP output itself with
//! register accesses alone ([`crate::step_dma::kill_step_outputs`]: each joint timer's
//! counter frozen, then its output forced inactive, or a pulse under way left to end at its
//! width; then the streams stopped). The rest needs the
//! step lock, which this interrupt, above the lock's level, must never take (issue 20:
//! the lock is BASEPRI at P2, so that it never holds this interrupt or the DIR changes
//! off), then stops a gripper burst the same way ([`crate::gripper::cut_at_stop`]:
//! counter stopped, output forced low; a servo PWM only under `ServoOnStop::Cut`; issue
//! 30). It pends the step service interrupt (P2), whose [`service`] halts the step
//! backend ([`arm_core::EStopLine::edge`] -> `StepShared::halt` -> `BoardSteps::stop`:
//! positions unwound to the pulses played, no run allowed to start until the input
//! closes) and wakes the trajectory task, which puts the controller in STOPPED and latches
//! it (RUNING and RETURN refused until the input is closed and a host sends ESTOP_RESET).
//! docs/BOARD.md, "Wired e-stop input", has the path from pin to STEP low.
//!
//! Category 1 (ESTOP_CATEGORY, issue 32) changes nothing here: this board's step side has
//! no ramped category 1: [`EXTI0`] stops it as category 0 whatever the setting (the
//! service halts the backend before `EStopLine::edge`, which then finds no run to ramp
//! and halts too); the controller then disables the drivers, category 1's end. A ramped
//! category 1 on the board needs [`EXTI0`]'s kill to ask the line first whether the
//! opening is left to a ramp, and a bound the trajectory task cannot miss (a timer).
//!
//! # Every interleaving
//!
//! The guarantee: once [`EXTI0`] has seen the input open, no STEP edge comes, and no run
//! starts until the input has closed. Nothing can delay [`EXTI0`] but a critical section
//! (PRIMASK), and the step path's are all short (the step lock does not mask it).
//!
//! 1. *Idle, or a run playing (timers and DMA doing the work).* The kill forces every
//!    output low and stops every counter and stream. A refill that was preempted (P2, in
//!    the lock) finishes writing a half that no stream reads any more and may arm the step
//!    clock; the step clock (P1) may still make DIR changes: no pulse either way. The
//!    service then halts the backend; the positions it unwinds are read from the stopped
//!    streams (their NDTR and half flags, which the kill leaves alone: a refill that ran
//!    in between consumed its flag and wrote its half, and that half then counts as
//!    unplayed, which it is).
//! 2. *A run's start under way (thread mode, in the lock, in pieces).* While the joints'
//!    buffers are primed (a piece per joint, the lock let go between them) no timer is
//!    touched: the service's halt, which may come between two pieces, takes back what the
//!    primed joints wrote and leaves the run idle. The last piece loads each timer and
//!    then starts the counters, each in a short critical section that first checks
//!    `KILL`, which the kill sets before its first write. A kill before a section: the
//!    section writes nothing and the start is taken back (every pulse written unwound, the
//!    run idle). A kill after the counters started: case 1. It cannot come inside a
//!    section.
//! 3. *A stop, an underrun or the run's end in progress (in the lock).* Their
//!    `stop_all_step_outputs` makes the same writes as the kill: the outputs stay off;
//!    the service's halt then finds the backend idle.
//! 4. *A start after the kill, before the service ran.* The service is pending at P2, so
//!    only code that held the lock when the kill came can run first (case 2): `KILL`
//!    is still set until the service has halted the backend (`StepShared`'s `halted`,
//!    under the lock, refuses every start from then on), and only then cleared.
//! 5. *The input bouncing.* Each opening sets [`OPENED`] before it pends the service;
//!    the service takes it (a swap) and halts, then releases only if the pin reads closed
//!    at that moment. An opening after that read pends the service again, whose halt
//!    comes before any thread-mode code (P2); `KILL` is set again by that opening.
//! 6. *The fault path.* It masks every interrupt and stops the outputs itself.
//! 7. *The gripper.* The kill cuts a burst the timer runs; a `start` it preempted before
//!    that start's critical section may start it again, and the controller's stop for
//!    the same opening, applied before the trajectory task handles anything else, cuts
//!    it then (`gripper.rs`, "Stops").

use core::sync::atomic::{AtomicBool, Ordering};

use arm_core::EStopLine;
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::{Peri, interrupt, pac, peripherals};

use crate::step_dma::STEP;
use crate::step_timer::STEP_TIMER;

/// The input's state, shared by [`EXTI0`] and the trajectory task.
pub static LINE: EStopLine = EStopLine::new();

/// The input's pin number on GPIOC (and so its EXTI line).
const PIN: usize = 0;

/// [`EXTI0`] ran since the service last looked: the service brings the line up to date.
static EDGE: AtomicBool = AtomicBool::new(false);

/// [`EXTI0`] saw the input open since the service last looked (it may have closed since):
/// the service halts the step backend.
static OPENED: AtomicBool = AtomicBool::new(false);

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
    // SAFETY: the handler touches EXTI's pending bit, GPIOC's input, the step outputs'
    // registers (kill_step_outputs), TIM15's CR1 and CCMR1 (cut_at_stop) and three
    // atomics, and pends the step service; it never takes the step lock.
    unsafe { interrupt::EXTI0.enable() };
    // An edge before the interrupt was enabled is pending and runs the handler; a level
    // that did not change is read here.
    if is_open() {
        interrupt::EXTI0.pend();
    }
}

/// The input's edge: STEP low first (register writes only), then the step service pended
/// for the halt and the trajectory task's wake-up ([`service`]).
#[interrupt]
fn EXTI0() {
    // rc_w1: writing 1 clears the pending bit. Cleared before the pin is read, so an edge
    // after the read pends the interrupt again.
    pac::EXTI.pr(0).write(|w| w.set_line(PIN, true));
    if is_open() {
        crate::step_dma::kill_step_outputs();
        // Then the gripper's burst (issue 30): after the STEP lines, two register writes.
        crate::gripper::cut_at_stop();
        OPENED.store(true, Ordering::SeqCst);
    }
    EDGE.store(true, Ordering::SeqCst);
    cortex_m::peripheral::NVIC::pend(crate::step_dma::SERVICE_IRQ);
}

/// The step service interrupt's share of the input (P2, may take the step lock): an
/// opening seen by [`EXTI0`] halts the step backend and records the input open (then the
/// outputs may be enabled again: no run starts while halted); a closed input lets runs
/// start again. Each wakes the trajectory task ([`EStopLine::edge`]). See the module
/// header for the interleavings.
pub fn service() {
    if !EDGE.swap(false, Ordering::SeqCst) {
        return;
    }
    let wake = &crate::BUS.step_progress;
    if OPENED.swap(false, Ordering::SeqCst) || is_open() {
        // EXTI0 has already forced every STEP output low, whatever the category: the run
        // is over here too (halted first, so the line finds no run left to a ramp and
        // stops as category 0; the controller still disables the drivers for category 1).
        // Without this, with the producer's warp (issue 32), the line would leave a
        // killed run "ramping" on the producer's count.
        STEP.halt();
        LINE.edge(true, &STEP, &STEP_TIMER, wake);
        crate::step_dma::kill_handled();
    }
    if !is_open() {
        LINE.edge(false, &STEP, &STEP_TIMER, wake);
    }
}
