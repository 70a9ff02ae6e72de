//! The step clock: TIM13 counting the 200 MHz timer clock, extended to 64 bits, with one
//! compare alarm for the step path's rare timed events: DIR changes at reversals and the
//! end of a run (`step_dma/` makes the pulses themselves in hardware).
//!
//! TIM13 is a 16-bit timer free-running over its whole range (328 us): its update
//! interrupt counts the wraps, and [`now_tick`] combines the count with the counter,
//! correcting for a wrap whose interrupt has not run yet. Compare channel 1 is armed at
//! the next event (the alarm's low 16 bits) when it is less than a whole wrap away; farther
//! events are looked at again at each wrap, which comes before them (board-logic's
//! `step_clock::compare_for` has the rule and its host test; armed only within half a wrap
//! until the Renode step tests, an alarm fired up to half a wrap, 164 us, late).
//! The interrupt runs at P1, above the DMA refills (P2) and below only
//! the wired e-stop input (P0, which stops the run anyway), so a DIR change waits at most
//! for a critical section (the longest is a refill's, ~2.5 us, covered by
//! the profile's `dir_latency_ns`, `step_dma::STEP_TIMING`).
//!
//! TIM13 shares its interrupt vector with TIM8's update, which is unused (TIM8's update
//! only requests DMA).

use core::cell::Cell;

use arm_core::hw::StepKick;
use board_logic::step_clock::{self, Compare};
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::{interrupt, pac};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;

use crate::step_dma::{STEP, STEP_TIMER_HZ};

/// Wraps of TIM13 counted, and the armed alarm (step clock tick, `u64::MAX`: none).
#[derive(Clone, Copy)]
struct ClockState {
    wraps: u64,
    alarm: u64,
}

static CLOCK: Mutex<CriticalSectionRawMutex, Cell<ClockState>> =
    Mutex::new(Cell::new(ClockState {
        wraps: 0,
        alarm: u64::MAX,
    }));

/// SR bits: update, CC1.
const SR_UIF: u32 = 1 << 0;
const SR_CC1IF: u32 = 1 << 1;
/// DIER bits.
const DIER_UIE: u32 = 1 << 0;
const DIER_CC1IE: u32 = 1 << 1;

/// Why the step clock cannot start.
#[derive(Clone, Copy, Debug, PartialEq, Eq, defmt::Format)]
pub struct ClockMismatch {
    /// The clock the timers actually get.
    pub actual_hz: u32,
}

/// Starts TIM13 free-running and enables its interrupt at P1. `timer_clock_hz` is the APB1
/// timer clock embassy configured; it must be the joint timers' [`STEP_TIMER_HZ`].
pub fn start(timer_clock_hz: u32) -> Result<StepTimer, ClockMismatch> {
    if timer_clock_hz != STEP_TIMER_HZ {
        return Err(ClockMismatch {
            actual_hz: timer_clock_hz,
        });
    }
    pac::RCC.apb1lenr().modify(|w| w.set_tim13en(true));
    let regs = pac::TIM13;
    regs.psc().write_value(0);
    regs.arr().write(|w| w.set_arr(u16::MAX));
    regs.egr().write(|w| w.set_ug(true));
    regs.sr().write_value(pac::timer::regs::Sr1ch(0));
    regs.dier().write_value(pac::timer::regs::Dier1ch(DIER_UIE));
    regs.cr1().modify(|w| w.set_cen(true));
    interrupt::TIM8_UP_TIM13.set_priority(Priority::P1);
    // SAFETY: the handler touches TIM13's registers, CLOCK and STEP (critical sections).
    unsafe { interrupt::TIM8_UP_TIM13.enable() };
    Ok(StepTimer { _private: () })
}

/// The step clock's tick (200 MHz, 64-bit: never wraps in practice). Right while TIM13's
/// interrupt runs within a whole wrap (327.68 us) of each wrap (board-logic's
/// `step_clock`: the update flag read before and after the counter).
pub fn now_tick() -> u64 {
    CLOCK.lock(|cell| {
        let state = cell.get();
        let pending_before = pac::TIM13.sr().read().0 & SR_UIF != 0;
        let counter = pac::TIM13.cnt().read().cnt();
        let pending_after = pac::TIM13.sr().read().0 & SR_UIF != 0;
        cell.set(state);
        step_clock::extended_tick(state.wraps, pending_before, counter, pending_after)
    })
}

/// Arms the alarm at step clock tick `at` (replacing any earlier one).
pub fn arm(at: u64) {
    CLOCK.lock(|cell| {
        let mut state = cell.get();
        state.alarm = at;
        cell.set(state);
    });
    program_compare();
}

/// No alarm.
pub fn disarm() {
    CLOCK.lock(|cell| {
        let mut state = cell.get();
        state.alarm = u64::MAX;
        cell.set(state);
    });
    let regs = pac::TIM13;
    regs.dier().write_value(pac::timer::regs::Dier1ch(DIER_UIE));
}

/// Sets CC1 for the alarm by board-logic's `step_clock::compare_for` (the rule and why it
/// is never late: there): the alarm's low 16 bits whenever it is less than a whole wrap
/// away, otherwise nothing until a wrap's interrupt calls this again; pends the interrupt
/// if the alarm is due already.
fn program_compare() {
    let alarm = CLOCK.lock(|cell| {
        let state = cell.get();
        let alarm = state.alarm;
        cell.set(state);
        alarm
    });
    let regs = pac::TIM13;
    let now = now_tick();
    if alarm == u64::MAX {
        regs.dier().write_value(pac::timer::regs::Dier1ch(DIER_UIE));
        return;
    }
    match step_clock::compare_for(alarm, now) {
        Compare::Due => cortex_m::peripheral::NVIC::pend(pac::Interrupt::TIM8_UP_TIM13),
        Compare::Match(value) => {
            regs.ccr(0).write(|w| w.set_ccr(value));
            regs.sr()
                .write_value(pac::timer::regs::Sr1ch(!SR_CC1IF & 0xFFFF));
            regs.dier()
                .write_value(pac::timer::regs::Dier1ch(DIER_UIE | DIER_CC1IE));
            // The counter may have passed the value before CCR1 took it (it would match
            // only a wrap later).
            if now_tick() >= alarm {
                cortex_m::peripheral::NVIC::pend(pac::Interrupt::TIM8_UP_TIM13);
            }
        }
        Compare::AfterWrap => {
            // Looked at again at the next wrap, which comes before the alarm.
            regs.dier().write_value(pac::timer::regs::Dier1ch(DIER_UIE));
        }
    }
}

/// Handle on the running step clock ([`StepKick`]).
#[derive(Clone, Copy)]
pub struct StepTimer {
    _private: (),
}

/// The step clock's [`StepKick`] for the wired e-stop input's interrupt (`estop.rs`): its
/// kick does nothing, so it needs no started clock.
pub static STEP_TIMER: StepTimer = StepTimer { _private: () };

impl StepKick for StepTimer {
    /// Nothing to do: a run is started and stopped by the backend itself (inside the
    /// critical section that starts or stops it), and new segments are picked up by the
    /// next refill.
    fn kick(&self) {}

    fn now_tick(&self) -> u64 {
        now_tick()
    }
}

#[interrupt]
fn TIM8_UP_TIM13() {
    let regs = pac::TIM13;
    let flags = regs.sr().read().0;
    // rc_w0 flags: writing 0 clears, 1 leaves alone.
    regs.sr().write_value(pac::timer::regs::Sr1ch(
        !(flags & (SR_UIF | SR_CC1IF)) & 0xFFFF,
    ));
    if flags & SR_UIF != 0 {
        CLOCK.lock(|cell| {
            let mut state = cell.get();
            state.wraps += 1;
            cell.set(state);
        });
    }
    let now = now_tick();
    let alarm = CLOCK.lock(|cell| {
        let state = cell.get();
        let alarm = state.alarm;
        cell.set(state);
        alarm
    });
    if alarm <= now {
        CLOCK.lock(|cell| {
            let mut state = cell.get();
            state.alarm = u64::MAX;
            cell.set(state);
        });
        // The backend makes the due DIR changes or ends the run, and re-arms.
        STEP.on_interrupt(&crate::BUS.step_progress, |steps| ((), steps.on_alarm(now)));
    }
    program_compare();
}
