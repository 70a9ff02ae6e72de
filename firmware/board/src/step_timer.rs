//! The step timer: TIM2 runs the step engine at its deadlines, at the highest interrupt
//! priority.
//!
//! TIM2 is a 32-bit counter at the 200 MHz APB1 timer clock (5 ns per tick), free-running
//! over its whole range. Time is extended to 64 bits by counting half periods: compare
//! channel 4 fires at the middle of the range, the update event at its end, and each adds
//! one to [`HALF_PERIODS`]. The parity of that count says which half the counter should be
//! in, so [`now_tick`] is correct without a lock even when it reads the counter just after
//! it wrapped and before the interrupt counted it (the method of embassy-stm32's own time
//! driver).
//!
//! Compare channel 1 is armed at the engine's next deadline. The interrupt polls the engine
//! through arm-core's [`on_step_timer`] (edges are written by [`StepDirWriter`] through
//! BSRR; finished segments wake the step task), then re-arms. Nothing here waits: there is
//! no delay loop; the STEP pulse width itself is a deadline of the engine.
//!
//! The engine is shared with the tasks in a critical-section mutex ([`STEP`]): they hold it
//! only to push a segment, start or stop, well under a microsecond.

use core::cell::RefCell;
use core::sync::atomic::{AtomicU32, Ordering, compiler_fence};

use arm_core::StepShared;
use arm_core::tasks::on_step_timer;
use arm_step::StepTiming;
use cortex_m::peripheral::NVIC;
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::peripherals::TIM2;
use embassy_stm32::timer::low_level::Timer;
use embassy_stm32::{Peri, interrupt, pac};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use static_cell::StaticCell;

use crate::late::Late;
use crate::pins::StepDirWriter;

/// Segments the engine holds on the interrupt's side: with the shortest common point
/// (1 ms) that is 64 ms of motion, far more than the controller task's worst wake-up
/// latency; 64 * 36 bytes of RAM.
pub const STEP_QUEUE: usize = 64;

/// TIM2's input clock (APB1 timer clock, see `clocks.rs`); checked at start-up.
pub const STEP_TIMER_HZ: u32 = 200_000_000;

/// Ticks per microsecond, for the driver timing below.
const TICKS_PER_US: u32 = STEP_TIMER_HZ / 1_000_000;

/// Driver timing: 2.5 us STEP high time (TB6600 needs 2.5 us, DRV8825 1.9 us, A4988 1 us)
/// and 5 us DIR setup (TB6600: 5 us; the others need less). That allows 133 kHz per joint,
/// above the controller's 100 kHz limit.
pub const STEP_TIMING: StepTiming = StepTiming {
    tick_hz: STEP_TIMER_HZ,
    pulse_width_ticks: 5 * TICKS_PER_US / 2,
    dir_setup_ticks: 5 * TICKS_PER_US,
};

// The driver timing must leave room for the controller's advertised step rate.
const _: () = assert!(STEP_TIMING.max_step_rate_hz() >= arm_core::config::BOARD_MAX_STEP_RATE_HZ);

/// The step engine shared by the interrupt and the tasks (arm-core's [`StepShared`]: the
/// engine, its stop count and the progress not yet collected, behind one critical-section
/// mutex). Built at the start of `main` ([`Late`]): `StepShared::new` has non-zero bytes,
/// which as a `const` initialiser would store all 4.9 KiB of it in flash.
pub static STEP: Late<StepShared<STEP_QUEUE>> = Late::new();

/// The STEP/DIR writer, handed to the interrupt by [`start`]; the interrupt does nothing
/// before.
static STEP_PINS: Mutex<CriticalSectionRawMutex, RefCell<Option<StepDirWriter>>> =
    Mutex::new(RefCell::new(None));

/// Half periods (2^31 ticks, 10.7 s) of TIM2 elapsed since start.
static HALF_PERIODS: AtomicU32 = AtomicU32::new(0);

/// The running TIM2, kept so that its clock stays on.
static TIMER: StaticCell<Timer<'static, TIM2>> = StaticCell::new();

/// TIM2 status flags that exist (UIF, CC1IF-CC4IF, TIF, CC1OF-CC4OF); the others are
/// reserved and written as 0.
const SR_FLAGS: u32 = 0x1E5F;
/// UIF.
const SR_UPDATE: u32 = 1 << 0;
/// CC1IF: the engine's deadline.
const SR_DEADLINE: u32 = 1 << 1;
/// CC4IF: the middle of the counter's range.
const SR_HALF: u32 = 1 << 4;
/// Where channel 4 fires: half of the 32-bit range.
const HALF_RANGE: u32 = 1 << 31;
/// Deadlines farther than this are not armed on channel 1 (its compare value would be
/// ambiguous); the half-period interrupts look again every 10.7 s instead.
const MAX_ARMED_TICKS: u64 = 1 << 31;
/// Engine polls in one interrupt before it yields to pending it again: bounds the time
/// spent when deadlines keep passing while it runs.
const MAX_POLLS_PER_INTERRUPT: u32 = 8;

/// Why the step timer cannot start.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub struct ClockMismatch {
    /// The clock TIM2 actually gets.
    pub actual_hz: u32,
}

/// Starts TIM2 free-running and hands the STEP/DIR writer to the interrupt.
pub fn start(tim: Peri<'static, TIM2>, pins: StepDirWriter) -> Result<StepTimer, ClockMismatch> {
    let timer = TIMER.init(Timer::new(tim));
    let actual_hz = timer.get_clock_frequency().0;
    if actual_hz != STEP_TIMER_HZ {
        return Err(ClockMismatch { actual_hz });
    }
    STEP_PINS.lock(|cell| *cell.borrow_mut() = Some(pins));

    let regs = pac::TIM2;
    regs.cr1()
        .write(|w| w.set_urs(pac::timer::vals::Urs::COUNTER_ONLY));
    regs.psc().write_value(0);
    regs.arr().write_value(u32::MAX);
    regs.ccr(3).write_value(HALF_RANGE);
    // Loads the prescaler; URS keeps it from counting as an overflow.
    regs.egr().write(|w| w.set_ug(true));
    regs.sr().write_value(pac::timer::regs::SrGp16(0));
    regs.dier().write(|w| {
        w.set_uie(true);
        w.set_ccie(3, true);
    });
    regs.cr1().modify(|w| w.set_cen(true));

    interrupt::TIM2.set_priority(Priority::P0);
    // SAFETY: the handler below only touches the shared stepper through its mutex, atomics
    // and TIM2's own registers.
    unsafe { interrupt::TIM2.enable() };
    Ok(StepTimer { _private: () })
}

/// Current step timer tick (64-bit, never wraps in practice: 2900 years at 200 MHz).
pub fn now_tick() -> u64 {
    let half_periods = HALF_PERIODS.load(Ordering::Acquire);
    compiler_fence(Ordering::Acquire);
    let counter = pac::TIM2.cnt().read();
    extend(half_periods, counter)
}

/// The 64-bit tick from the half periods counted so far and the 32-bit counter read after.
/// An even count means the counter should be in its lower half: if it is in the upper
/// half, the half-period interrupt has not run yet, and the XOR still gives the right
/// tick; likewise after a wrap with an odd count.
const fn extend(half_periods: u32, counter: u32) -> u64 {
    ((half_periods as u64) << 31) + (counter ^ ((half_periods & 1) << 31)) as u64
}

// The cases that matter, checked at compile time: before and after each interrupt.
const _: () = {
    const HALF: u64 = 1 << 31;
    assert!(extend(0, 5) == 5);
    // Passed the middle, CC4 interrupt not yet run / run.
    assert!(extend(0, HALF_RANGE + 5) == HALF + 5);
    assert!(extend(1, HALF_RANGE + 5) == HALF + 5);
    // Wrapped, update interrupt not yet run / run.
    assert!(extend(1, 5) == 2 * HALF + 5);
    assert!(extend(2, 5) == 2 * HALF + 5);
    // Many periods later.
    assert!(extend(7, u32::MAX) == 8 * HALF - 1);
    assert!(extend(8, 0) == 8 * HALF);
};

/// Handle on the running step timer ([`arm_core::hw::StepKick`]).
#[derive(Clone, Copy)]
pub struct StepTimer {
    _private: (),
}

impl arm_core::hw::StepKick for StepTimer {
    fn kick(&self) {
        NVIC::pend(pac::Interrupt::TIM2);
    }

    fn now_tick(&self) -> u64 {
        now_tick()
    }
}

/// Arms channel 1 for `deadline`; returns true if the deadline has already passed (poll
/// again now).
fn arm(deadline: Option<u64>) -> bool {
    let regs = pac::TIM2;
    let Some(deadline) = deadline else {
        regs.dier().modify(|w| w.set_ccie(0, false));
        return false;
    };
    let now = now_tick();
    if deadline <= now {
        return true;
    }
    if deadline - now >= MAX_ARMED_TICKS {
        regs.dier().modify(|w| w.set_ccie(0, false));
        return false;
    }
    // The compare value is the deadline's low 32 bits: the counter reaches it exactly at
    // the deadline, since that is less than half a wrap away.
    regs.ccr(0).write_value(deadline as u32);
    // A match of the old compare value may have left CC1IF set: clear it, or it would
    // fire at once (harmless, but a wasted poll).
    regs.sr()
        .write_value(pac::timer::regs::SrGp16(!SR_DEADLINE & SR_FLAGS));
    regs.dier().modify(|w| w.set_ccie(0, true));
    // The counter may have passed the compare value while it was being written.
    now_tick() >= deadline
}

/// Polls the engine until its next deadline is in the future, and arms it.
fn service() {
    for _ in 0..MAX_POLLS_PER_INTERRUPT {
        let now = now_tick();
        let polled = STEP_PINS.lock(|cell| {
            let mut cell = cell.borrow_mut();
            let pins = cell.as_mut()?;
            Some(on_step_timer(&STEP, now, pins, &crate::BUS.step_wake))
        });
        let Some(next_deadline) = polled else {
            return;
        };
        if !arm(next_deadline) {
            return;
        }
    }
    // Still behind: run again right after returning, letting nothing of equal priority
    // starve (there is nothing else at P0).
    NVIC::pend(pac::Interrupt::TIM2);
}

#[interrupt]
fn TIM2() {
    let regs = pac::TIM2;
    let flags = regs.sr().read().0 & SR_FLAGS;
    // rc_w0 flags: writing 0 clears, 1 leaves alone, so flags raised since the read stay.
    regs.sr()
        .write_value(pac::timer::regs::SrGp16(!flags & SR_FLAGS));
    if flags & SR_UPDATE != 0 {
        HALF_PERIODS.fetch_add(1, Ordering::AcqRel);
    }
    if flags & SR_HALF != 0 {
        HALF_PERIODS.fetch_add(1, Ordering::AcqRel);
    }
    // A deadline (CC1), a half period, or a kick (pended, no flag): the engine decides
    // what is due.
    service();
}
