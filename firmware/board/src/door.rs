//! The safety-door input (issue 32): PF4 (Morpho CN11/CN12), a normally-closed contact to
//! GND, read with the internal pull-up, so that an open door *and* a broken wire read high:
//! open. EXTI line 4 interrupts on both edges (its own vector, EXTI4; docs/BOARD.md
//! "Safety door input"). Unlike the e-stop's ([`crate::estop`]) its handler halts nothing:
//! it records the level in [`LINE`] and wakes the trajectory task, which holds the run
//! along its path (arm-core's `Controller::door_input`: HOLD's ramp, RUNING and RESUME
//! refused `DOOR_OPEN` while open). On this board's step side, which has no time warp
//! yet, a run cannot hold, so the controller stops it instead (as a STOPPED; PROTOCOL.md,
//! "Safety door"). An opening is never lost: `DoorLine` keeps it until the task takes it.
//!
//! Opt-in (feature `door-input`): with the pull-up, a board with nothing on PF4 reads the
//! door open and would refuse every run `DOOR_OPEN`; an arm with a door builds with it.
//!
//! Priority P4 (main.rs's table): the handler only records and wakes a task, whose own
//! latency is the stop's; it must never delay the e-stop, the switches or the step path.

use arm_core::DoorLine;
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::{Peri, interrupt, pac, peripherals};

/// The input's state, shared by [`EXTI4`] and the trajectory task.
pub static LINE: DoorLine = DoorLine::new();

/// The input's pin number on GPIOF (and so its EXTI line).
const PIN: usize = 4;

/// SYSCFG_EXTICRx's code for port F.
const PORT_F: u8 = 5;

/// Whether the door reads open (high: the contact no longer pulls it to GND).
fn is_open() -> bool {
    pac::GPIOF.idr().read().idr(PIN) == pac::gpio::vals::Idr::HIGH
}

/// Makes PF4 an input with its pull-up, routes it to EXTI line 4 on both edges and
/// enables the interrupt at P4; the level now is recorded (a door open at boot refuses
/// RUNING from the first frame). Call after the bus is built.
pub fn start(_pin: Peri<'static, peripherals::PF4>) {
    let port = pac::GPIOF;
    port.pupdr()
        .modify(|w| w.set_pupdr(PIN, pac::gpio::vals::Pupdr::PULL_UP));
    port.moder()
        .modify(|w| w.set_moder(PIN, pac::gpio::vals::Moder::INPUT));
    pac::RCC.apb4enr().modify(|w| w.set_syscfgen(true));
    // EXTICR2's field 0 is line 4.
    pac::SYSCFG
        .exticr(PIN / 4)
        .modify(|w| w.set_exti(PIN % 4, PORT_F));
    let exti = pac::EXTI;
    exti.rtsr(0).modify(|w| w.set_line(PIN, true));
    exti.ftsr(0).modify(|w| w.set_line(PIN, true));
    exti.imr(0).modify(|w| w.set_line(PIN, true));
    interrupt::EXTI4.set_priority(Priority::P4);
    // SAFETY: the handler touches EXTI's pending bit, GPIOF's input and `LINE` (a critical
    // section), and signals the bus; it never takes the step lock.
    unsafe { interrupt::EXTI4.enable() };
    // An edge before the interrupt was enabled is pending and runs the handler; a level
    // that did not change is read here.
    if is_open() {
        interrupt::EXTI4.pend();
    }
}

/// The door's edge: the level recorded, the trajectory task woken.
#[interrupt]
fn EXTI4() {
    // rc_w1: cleared before the pin is read, so an edge after the read pends it again.
    pac::EXTI.pr(0).write(|w| w.set_line(PIN, true));
    LINE.set(is_open(), &crate::BUS.step_progress);
}
