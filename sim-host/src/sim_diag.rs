//! The simulator's own DIAG figures (issue 34): what it can measure of itself, in its own
//! clocks, never the board's. The DIAG report's fields mean here:
//!
//! - **masked spans**, `cpu_hz` = 1,000,000,000 (**host ns**): the longest time the step
//!   thread held the step lock while playing the step hardware (one play: edges, DIR
//!   changes, the producer's refills). The step lock is a critical section, and on the
//!   host every critical section of the simulator is one global lock, so this is how long
//!   the step side held off the trajectory task and the receive path. `masked_opener` is 0:
//!   a host has no address to give. Critical sections of the other tasks are not timed.
//! - **DIR changes**, `step_hz` = the simulated step clock: how many ticks after its due
//!   tick the step thread played each DIR change (the thread plays edges in bulk when it
//!   wakes; the motors and the VCD trace take the exact tick, so this is the simulator's
//!   lateness in simulated time, not an error in the pulses).
//! - **step DMA slack**: no refill measured. The simulator's refills are computed at their
//!   exact tick inside a play (no DMA transfer, nothing can land late), so there is no
//!   slack to measure: `dma_slack_min_ticks` stays `NO_REFILL` and `dma_refills` 0.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering};
use std::time::Duration;

/// The simulated step clock, Hz (set when the controller is wired).
static STEP_HZ: AtomicU32 = AtomicU32::new(0);
/// The longest play under the step lock, host ns.
static PLAY_MAX_NS: AtomicU64 = AtomicU64::new(0);
/// Plays timed.
static PLAYS: AtomicU32 = AtomicU32::new(0);
/// The latest DIR change played, ticks after its due tick; `u64::MAX`: none yet.
static DIR_LATE_MAX: AtomicU64 = AtomicU64::new(u64::MAX);
/// DIR changes played.
static DIR_WRITES: AtomicU32 = AtomicU32::new(0);

/// The step clock's rate, for the report.
pub fn set_step_hz(hz: u32) {
    STEP_HZ.store(hz, Ordering::Relaxed);
}

/// One play of the step hardware under the step lock took `took`.
pub fn played(took: Duration) {
    let ns = u64::try_from(took.as_nanos()).unwrap_or(u64::MAX);
    PLAY_MAX_NS.fetch_max(ns, Ordering::Relaxed);
    PLAYS.fetch_add(1, Ordering::Relaxed);
}

/// A DIR change due at step clock tick `due` was played at tick `now`.
pub fn dir_played(due: u64, now: u64) {
    let late = now.saturating_sub(due);
    let _ = DIR_LATE_MAX.fetch_update(Ordering::Relaxed, Ordering::Relaxed, |max| {
        (max == u64::MAX || late > max).then_some(late)
    });
    DIR_WRITES.fetch_add(1, Ordering::Relaxed);
}

/// The DIAG report (the controller's diag source).
pub fn report() -> protocol::Diag {
    let late = DIR_LATE_MAX.load(Ordering::Relaxed);
    protocol::Diag {
        cpu_hz: 1_000_000_000,
        masked_max_cycles: u32::try_from(PLAY_MAX_NS.load(Ordering::Relaxed)).unwrap_or(u32::MAX),
        masked_opener: 0,
        masked_spans: PLAYS.load(Ordering::Relaxed),
        step_hz: STEP_HZ.load(Ordering::Relaxed),
        dir_late_max_ticks: if late == u64::MAX {
            protocol::Diag::NO_DIR_WRITE
        } else {
            i32::try_from(late).unwrap_or(i32::MAX)
        },
        dir_writes: DIR_WRITES.load(Ordering::Relaxed),
        dma_slack_min_ticks: protocol::Diag::NO_REFILL,
        dma_refills: 0,
    }
}
