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
//!
//! **DIR never late, by construction (issue 20).** The interrupt runs at P1, above the DMA
//! refills (P2) and below only the wired e-stop input (P0, which stops the run anyway).
//! It never takes the step lock (`step_dma::STEP`, a BASEPRI lock that masks P2 and
//! below, so no step-path section holds this interrupt off): the DIR changes come from
//! `step_dma::DIRS`, a lock-free ring per joint that the refills publish into
//! (arm-step's `DirQueues`), and the run's end, which needs the producer, is handed to the
//! step service interrupt (`step_dma::SERVICE_IRQ`, P2) by pending it. What this interrupt
//! shares with the step path is [`CLOCK`] (wraps, alarm, the run's origin and end), behind
//! a critical section of a few dozen instructions (every access below is one such
//! section, `program_compare` included, so that the compare register is never programmed
//! from a stale alarm).
//!
//! Who moves the alarm, and why no DIR change is missed: the producer side (refills, the
//! run's start, the service) only ever moves it *earlier* ([`arm`]: the earliest queued DIR
//! change or the run's end), from a minimum it read from the queues; this interrupt only
//! consumes changes that are due and then sets it to the earliest one left. A producer
//! that read the queues before this interrupt consumed an entry arms at a tick already
//! made: one spurious interrupt, which finds nothing due and re-arms. [`disarm`] (a stop)
//! sets it to none; until the next [`arm`] this interrupt does not look at the queues, so
//! the stop may clear them.
//!
//! TIM13 shares its interrupt vector with TIM8's update, which is unused (TIM8's update
//! only requests DMA).

use core::cell::Cell;

use arm_core::hw::StepKick;
use board_logic::step_clock::{self, Compare};
use embassy_stm32::interrupt::InterruptExt;
use embassy_stm32::{interrupt, pac};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;

use arm_step::{DirChange, MAX_JOINTS};

use crate::pins;
use crate::step_dma::{DIRS, SERVICE_IRQ, STEP_TIMER_HZ};

/// Wraps of TIM13 counted, the armed alarm, and the run the alarms are for.
#[derive(Clone, Copy)]
struct ClockState {
    wraps: u64,
    /// Step clock tick of the next look at the DIR queues and the run's end; `u64::MAX`:
    /// none.
    alarm: u64,
    /// Step clock tick of the run's tick 0 (the joint timers' start): the DIR changes'
    /// and the end's ticks are relative to it.
    origin: u64,
    /// The run's end, run ticks (the producer's `run_end_tick`); `u64::MAX`: not known.
    end: u64,
}

static CLOCK: Mutex<CriticalSectionRawMutex, Cell<ClockState>> =
    Mutex::new(Cell::new(ClockState {
        wraps: 0,
        alarm: u64::MAX,
        origin: 0,
        end: u64::MAX,
    }));

/// SR bits: update, CC1.
const SR_UIF: u32 = 1 << 0;
const SR_CC1IF: u32 = 1 << 1;
/// DIER bits.
const DIER_UIE: u32 = 1 << 0;
const DIER_CC1IE: u32 = 1 << 1;

/// Why the step clock cannot start: a timer bus whose timer clock is not
/// [`STEP_TIMER_HZ`] (board-logic's `step_clock::check_timer_clocks`).
pub use board_logic::step_clock::ClockMismatch;

/// Starts TIM13 free-running and enables its interrupt at P1 (`step_dma::DIR_PRIORITY`).
/// `apb1_timer_hz` and `apb2_timer_hz` are the timer clocks embassy configured (TIM13 and
/// joints 0-3 on APB1, joints 4-7 on APB2; issue 34: APB2 was not checked); both must be
/// the joint timers' [`STEP_TIMER_HZ`].
pub fn start(apb1_timer_hz: u32, apb2_timer_hz: u32) -> Result<StepTimer, ClockMismatch> {
    step_clock::check_timer_clocks(apb1_timer_hz, apb2_timer_hz, STEP_TIMER_HZ)?;
    pac::RCC.apb1lenr().modify(|w| w.set_tim13en(true));
    let regs = pac::TIM13;
    regs.psc().write_value(0);
    regs.arr().write(|w| w.set_arr(u16::MAX));
    regs.egr().write(|w| w.set_ug(true));
    regs.sr().write_value(pac::timer::regs::Sr1ch(0));
    regs.dier().write_value(pac::timer::regs::Dier1ch(DIER_UIE));
    regs.cr1().modify(|w| w.set_cen(true));
    interrupt::TIM8_UP_TIM13.set_priority(crate::step_dma::DIR_PRIORITY);
    // SAFETY: the handler touches TIM13's registers, CLOCK (critical sections), the DIR
    // queues (lock-free, as their consumer) and the DIR pins; it pends the service
    // interrupt. It never takes the step lock.
    unsafe { interrupt::TIM8_UP_TIM13.enable() };
    Ok(StepTimer { _private: () })
}

/// The step clock's tick (200 MHz, 64-bit: never wraps in practice). Right while TIM13's
/// interrupt runs within a whole wrap (327.68 us) of each wrap (board-logic's
/// `step_clock`: the update flag read before and after the counter).
pub fn now_tick() -> u64 {
    CLOCK.lock(|cell| tick_at(cell.get().wraps))
}

/// The tick from `wraps` counted and the counter (inside [`CLOCK`]'s critical section).
fn tick_at(wraps: u64) -> u64 {
    let pending_before = pac::TIM13.sr().read().0 & SR_UIF != 0;
    let counter = pac::TIM13.cnt().read().cnt();
    let pending_after = pac::TIM13.sr().read().0 & SR_UIF != 0;
    step_clock::extended_tick(wraps, pending_before, counter, pending_after)
}

/// A run's timers started at step clock tick `origin`: no alarm yet, end unknown.
pub fn start_run(origin: u64) {
    CLOCK.lock(|cell| {
        let mut state = cell.get();
        state.origin = origin;
        state.alarm = u64::MAX;
        state.end = u64::MAX;
        cell.set(state);
    });
}

/// The producer side's alarm: `earliest_dir` (the earliest queued DIR change, run ticks)
/// and `end` (the run's end if known, run ticks, which replaces the one known before).
/// The alarm only moves earlier (see the module header).
pub fn arm(earliest_dir: Option<u64>, end: Option<u64>) {
    CLOCK.lock(|cell| {
        let mut state = cell.get();
        state.end = end.unwrap_or(u64::MAX);
        let next = earliest_dir.unwrap_or(u64::MAX).min(state.end);
        if next != u64::MAX {
            state.alarm = state.alarm.min(state.origin.saturating_add(next));
        }
        cell.set(state);
        program_compare(state);
    });
}

/// No alarm (the run stopped or ended): the interrupt no longer looks at the DIR queues.
pub fn disarm() {
    CLOCK.lock(|cell| {
        let mut state = cell.get();
        state.alarm = u64::MAX;
        state.end = u64::MAX;
        cell.set(state);
        pac::TIM13
            .dier()
            .write_value(pac::timer::regs::Dier1ch(DIER_UIE));
    });
}

/// Sets CC1 for the alarm by board-logic's `step_clock::compare_for` (the rule and why it
/// is never late: there): the alarm's low 16 bits whenever it is less than a whole wrap
/// away, otherwise nothing until a wrap's interrupt calls this again; pends the interrupt
/// if the alarm is due already. Inside [`CLOCK`]'s critical section, with its state.
fn program_compare(state: ClockState) {
    let regs = pac::TIM13;
    let alarm = state.alarm;
    if alarm == u64::MAX {
        regs.dier().write_value(pac::timer::regs::Dier1ch(DIER_UIE));
        return;
    }
    let now = tick_at(state.wraps);
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
            if tick_at(state.wraps) >= alarm {
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
    /// Nothing to do: a run is started and stopped by the backend itself (under the step
    /// lock that starts or stops it), and new segments are picked up by the next refill.
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
    // Count the wrap; take the alarm if it is due (none until re-armed below).
    let due = CLOCK.lock(|cell| {
        let mut state = cell.get();
        if flags & SR_UIF != 0 {
            state.wraps += 1;
        }
        let now = tick_at(state.wraps);
        let due = state.alarm <= now;
        if due {
            state.alarm = u64::MAX;
        }
        cell.set(state);
        due.then_some((now, state.origin, state.end))
    });
    if let Some((now, origin, end)) = due {
        // The DIR changes that are due, from the lock-free queues: nothing the step path
        // does can hold this off (module header).
        let at = now.saturating_sub(origin);
        for joint in 0..MAX_JOINTS {
            while let Some(DirChange { tick, positive }) = DIRS.peek(joint) {
                if tick > at {
                    break;
                }
                pins::set_direction(joint, positive);
                // The DIAG report's DIR lateness: the counter against the due tick.
                crate::diag::dir_written(regs.cnt().read().cnt(), origin.saturating_add(tick));
                DIRS.pop(joint);
            }
        }
        let mut next = DIRS.earliest().unwrap_or(u64::MAX);
        if end <= at {
            // The run's end needs the producer: the service interrupt (P2) takes the step
            // lock, checks that nothing was pushed since, and stops the run.
            cortex_m::peripheral::NVIC::pend(SERVICE_IRQ);
        } else {
            next = next.min(end);
        }
        CLOCK.lock(|cell| {
            let mut state = cell.get();
            if next != u64::MAX {
                state.alarm = state.alarm.min(origin.saturating_add(next));
            }
            cell.set(state);
        });
    }
    CLOCK.lock(|cell| program_compare(cell.get()));
}
