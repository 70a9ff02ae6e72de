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
//! # Category 1 (issue 32)
//! With the stop category set to 1 (ESTOP_CATEGORY, [`EStopLine::set_category`]) an
//! opening while a run plays on a step side with a time warp ([`StepShared::rate_now`]
//! says so: the simulator's; the boards' have none and stop as category 0) is left to a
//! controlled stop: the handler only blocks new runs ([`StepShared::block_starts`]),
//! records the opening as `controlled` and wakes the task, which ramps the run to a
//! standstill within the accelerations, then disables the drivers and latches
//! ([`crate::Controller::estop_controlled`]). Every other opening halts at once as in
//! category 0: no run to ramp, no warp, or a ramp already under way (a second opening).
//! The task bounds the ramp ([`crate::controller::estop_ramp_bound_us`]) and
//! halts when it is passed.
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
    /// Every opening since the last take was left to a category 1 controlled stop (the
    /// handler halted nothing): the task ramps the run down. False when any of them
    /// halted.
    pub controlled: bool,
}

/// The line's state under its lock.
#[derive(Clone, Copy, Debug, Default)]
struct LineState {
    /// What the task takes.
    sample: EStopSample,
    /// Category 1 is set ([`EStopLine::set_category`]).
    category_1: bool,
    /// A category 1 ramp is under way (set by the opening left to it, cleared by
    /// [`EStopLine::ramp_over`]): another opening halts at once.
    ramping: bool,
}

/// The wired e-stop input as the edge handler and the trajectory task share it. Put one
/// in a `static` (`new` is `const`).
pub struct EStopLine {
    state: Mutex<Cs, Cell<LineState>>,
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
            state: Mutex::new(Cell::new(LineState {
                sample: EStopSample {
                    open: false,
                    opened: false,
                    controlled: false,
                },
                category_1: false,
                ramping: false,
            })),
        }
    }

    /// The edge handler's work: the input is now `open` (or closed). Opening halts the
    /// step backend at once, before anything else ([`StepShared::halt`], then `kick`),
    /// unless category 1 leaves it to a controlled stop (see the module header: a run
    /// under way on a step side with a warp and no ramp yet; then new runs are blocked
    /// only); closing lets runs start again ([`StepShared::release`]). Then the level is
    /// recorded and the trajectory task woken with `wake` (the bus's `step_progress`).
    /// Callable from any context; never waits.
    pub fn edge<const Q: usize, B: StepBackend, M: embassy_sync::blocking_mutex::raw::RawMutex>(
        &self,
        open: bool,
        step: &StepShared<Q, B, M>,
        kick: &impl StepKick,
        wake: &Signal<Cs, ()>,
    ) {
        // Decided from a look at the line, acted on outside its lock (as before category
        // 1: the halt takes only the step lock, never inside a critical section, which
        // would hold off the DIR changes and the other P0 inputs on the NUCLEO), then
        // recorded. The handler is never re-entered (one interrupt, or one thread under
        // the simulator's lock); the task's `ramp_over` in between changes nothing here.
        let (category_1, ramping) = self.state.lock(|s| {
            let line = s.get();
            (line.category_1, line.ramping)
        });
        let controlled = open && category_1 && !ramping && step.rate_now(kick.now_tick()).is_some();
        if controlled {
            step.block_starts();
        } else if open {
            step.halt();
            kick.kick();
        } else {
            step.release();
        }
        self.state.lock(|s| {
            let mut line = s.get();
            if open {
                line.ramping = controlled;
                let all_controlled = !line.sample.opened || line.sample.controlled;
                line.sample.controlled = controlled && all_controlled;
                line.sample.opened = true;
            }
            line.sample.open = open;
            s.set(line);
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
            if !s.get().sample.open {
                step.release();
            }
        });
    }

    /// Whether the input is open now.
    pub fn is_open(&self) -> bool {
        self.state.lock(|s| s.get().sample.open)
    }

    /// The level now and whether it opened since the last call (which this call clears).
    pub fn take(&self) -> EStopSample {
        self.state.lock(|s| {
            let mut line = s.get();
            let sample = line.sample;
            line.sample.opened = false;
            line.sample.controlled = false;
            s.set(line);
            sample
        })
    }

    /// The stop category the controller's settings say (ESTOP_CATEGORY); the trajectory
    /// task sets it before it looks at the line, so that the handler knows it.
    pub fn set_category(&self, category: protocol::EStopCategory) {
        self.state.lock(|s| {
            let mut line = s.get();
            line.category_1 = category == protocol::EStopCategory::Controlled;
            s.set(line);
        });
    }

    /// The trajectory task's controlled stop ended (or never began): the next opening
    /// may be left to one again. Nothing while an opening is still to be taken (its
    /// ramp is the one under way).
    pub fn ramp_over(&self) {
        self.state.lock(|s| {
            let mut line = s.get();
            if !line.sample.opened {
                line.ramping = false;
            }
            s.set(line);
        });
    }
}
