//! The wired e-stop input (issue 18, part 3): a normally-closed contact whose opening
//! stops every STEP output at once and latches the controller in STOPPED.
//!
//! Two halves, so that the stop waits for no task:
//! 1. The handler that sees the input's edge (the board's EXTI interrupt, above every
//!    other; the simulator's input thread; a test) calls [`EStopLine::edge`]. On opening it
//!    halts the step backend right there ([`StepShared::halt`]: the backend's emergency
//!    stop, and no run may start until the input closes) and kicks the step interrupt,
//!    as `TaskPlant::stop` does for a STOPPED. Then it records the level and wakes the
//!    trajectory task (through `bus.step_progress`, which it always waits on).
//! 2. Whatever woke it, the trajectory task brings the controller up to date with
//!    [`EStopLine::take`] before it handles anything else (a STOPPED, a datagram, step
//!    progress): an opening is the effect of a STOPPED plus the latch
//!    ([`crate::Controller::estop_input`]: state STOPPED, buffer dropped, a LOCATION),
//!    so RUNING and RETURN are refused `ESTOP_LATCHED` until the input is closed and a
//!    host sends ESTOP_RESET.
//!
//! An opening is never lost: [`EStopSample::opened`] stays set until the task takes it,
//! so an input that opens and closes again before the task runs still latches.
//!
//! The line is the same for every board: what is hardware-specific is only who calls
//! [`EStopLine::edge`] with which level (docs/BOARD.md has the NUCLEO's pin and interrupt,
//! sim-host/README.md the simulator's option and signals). A board without the input
//! passes no line to the trajectory task; STATUS then shows the input closed.

use core::cell::Cell;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::signal::Signal;

use crate::bus::Cs;
use crate::hw::StepKick;
use crate::step_shared::{StepBackend, StepShared};

/// What the trajectory task learns from the input ([`EStopLine::take`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EStopSample {
    /// The input is open now.
    pub open: bool,
    /// It opened at least once since the last [`EStopLine::take`] (it may have closed
    /// again since).
    pub opened: bool,
}

/// The wired e-stop input as the edge handler and the trajectory task share it. Put one
/// in a `static` (`new` is `const`).
pub struct EStopLine {
    state: Mutex<Cs, Cell<EStopSample>>,
}

impl Default for EStopLine {
    fn default() -> Self {
        Self::new()
    }
}

impl EStopLine {
    /// Closed, nothing to take.
    pub const fn new() -> Self {
        EStopLine {
            state: Mutex::new(Cell::new(EStopSample {
                open: false,
                opened: false,
            })),
        }
    }

    /// The edge handler's work: the input is now `open` (or closed). Opening halts the
    /// step backend at once, before anything else ([`StepShared::halt`], then `kick`);
    /// closing lets runs start again ([`StepShared::release`]). Then the level is
    /// recorded and the trajectory task woken with `wake` (the bus's `step_progress`).
    /// Callable from any context; never waits.
    pub fn edge<const Q: usize, B: StepBackend, M: embassy_sync::blocking_mutex::raw::RawMutex>(
        &self,
        open: bool,
        step: &StepShared<Q, B, M>,
        kick: &impl StepKick,
        wake: &Signal<Cs, ()>,
    ) {
        if open {
            step.halt();
            kick.kick();
        } else {
            step.release();
        }
        self.state.lock(|s| {
            let was = s.get();
            s.set(EStopSample {
                open,
                opened: was.opened || open,
            });
        });
        wake.signal(());
    }

    /// Lifts a halt another stop set ([`crate::switch_line::SwitchLine::resume`]) unless
    /// this input is open now; under this line's lock, so an opening cannot slip between
    /// the look and the release.
    pub fn release_unless_open<
        const Q: usize,
        B: StepBackend,
        M: embassy_sync::blocking_mutex::raw::RawMutex,
    >(
        &self,
        step: &StepShared<Q, B, M>,
    ) {
        self.state.lock(|s| {
            if !s.get().open {
                step.release();
            }
        });
    }

    /// Whether the input is open now.
    pub fn is_open(&self) -> bool {
        self.state.lock(|s| s.get().open)
    }

    /// The level now and whether it opened since the last call (which this call clears).
    pub fn take(&self) -> EStopSample {
        self.state.lock(|s| {
            let sample = s.get();
            s.set(EStopSample {
                open: sample.open,
                opened: false,
            });
            sample
        })
    }
}
