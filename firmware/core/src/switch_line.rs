//! The switch inputs as the edge handler and the trajectory task share them (issue 33),
//! built as the wired e-stop's [`crate::EStopLine`]:
//! 1. The handler that sees an input's edge (the board's EXTI interrupt; the simulator's
//!    joint model; a test) calls [`SwitchLine::edge`] with the instant and the joint's
//!    count. A limit switch becoming active halts the step backend right there
//!    ([`StepShared::halt`]: no further pulse, no run starts) and kicks the step interrupt,
//!    before any task runs. Then the event is queued and the trajectory task woken.
//! 2. The trajectory task, before anything else, takes the events ([`SwitchLine::take`]),
//!    hands them to the controller ([`crate::Controller::limit_switch`]: STOPPED's work and
//!    the latch), and then lifts the halt ([`SwitchLine::resume`]) unless the wired e-stop
//!    input is open: from then on the controller's latch refuses runs.
//!
//! A trip is never lost: the first one since the last [`SwitchLine::take`] is kept apart
//! from the queue, so a queue overrun (an input chattering faster than the task runs)
//! drops only later events.

use core::cell::RefCell;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::signal::Signal;
use heapless::Deque;

use crate::bus::Cs;
use crate::estop_input::EStopLine;
use crate::hw::StepKick;
use crate::step_shared::{StepBackend, StepShared};
use crate::switches::{Side, Switch, SwitchBank, SwitchConfig, SwitchEvent};

/// Switch events queued between two looks of the trajectory task: every input (8 joints x
/// 3) changing twice (activation and release) before the task runs, which a task woken
/// at each edge does not let happen; more are dropped (never the first trip).
pub const SWITCH_EVENTS: usize = 48;

struct State {
    bank: SwitchBank,
    events: Deque<SwitchEvent, SWITCH_EVENTS>,
    /// The first trip since the last take, kept whatever the queue did.
    first_trip: Option<SwitchEvent>,
    /// The halt is this line's (a trip not yet handed to the controller).
    halting: bool,
    /// The limit whose trips do not halt (the homing cycle's switch, when it is also the
    /// limit; [`SwitchLine::set_mask`]).
    mask: Option<(u8, Side)>,
}

/// The switch inputs, shared by the edge handler and the trajectory task. Put one in a
/// `static` (`new` is `const`).
pub struct SwitchLine {
    state: Mutex<Cs, RefCell<State>>,
}

impl SwitchLine {
    /// Inputs as `config` says; none active.
    pub const fn new(config: SwitchConfig) -> Self {
        SwitchLine {
            state: Mutex::new(RefCell::new(State {
                bank: SwitchBank::new(config),
                events: Deque::new(),
                first_trip: None,
                halting: false,
                mask: None,
            })),
        }
    }

    /// Whether any input is fitted.
    pub fn any_fitted(&self) -> bool {
        self.state.lock(|s| s.borrow().bank.any_fitted())
    }

    /// Whether `joint`'s `switch` counts as active now.
    pub fn is_active(&self, joint: u8, switch: Switch) -> bool {
        self.state
            .lock(|s| s.borrow().bank.is_active(joint, switch))
    }

    /// The limit whose trips must not halt the steps (issue 33: the switch the homing
    /// cycle homes on, when it is also that side's limit; the controller sets it through
    /// its plant before the move that may reach it). Its trips are still handed to the
    /// controller, whose hard limits mask them the same way.
    pub fn set_mask(&self, mask: Option<(u8, Side)>) {
        self.state.lock(|s| s.borrow_mut().mask = mask);
    }

    /// Whether a trip of `joint`'s `side` limit is masked now ([`Self::set_mask`]): a
    /// simulator's model halting its own step playback asks.
    pub fn is_masked(&self, joint: u8, side: Side) -> bool {
        self.state.lock(|s| s.borrow().mask == Some((joint, side)))
    }

    /// The edge handler's work: `joint`'s `switch` reads `level` at `at_us`, the joint's
    /// count being `position`. A limit trip halts the steps at once and kicks the step
    /// interrupt; any event wakes the trajectory task with `wake`. Never waits.
    #[allow(clippy::too_many_arguments)] // the edge's facts, then what it acts on
    pub fn edge<const Q: usize, B: StepBackend, M: embassy_sync::blocking_mutex::raw::RawMutex>(
        &self,
        joint: u8,
        switch: Switch,
        level: bool,
        position: i32,
        at_us: u64,
        step: &StepShared<Q, B, M>,
        kick: &impl StepKick,
        wake: &Signal<Cs, ()>,
    ) {
        let event = self.state.lock(|s| {
            let mut s = s.borrow_mut();
            let mut event = s.bank.edge(joint, switch, level, position, at_us)?;
            let halts = match event {
                // Masked at its edge: masked for good, whenever the controller takes it
                // (the homing cycle may have moved on to another joint by then).
                SwitchEvent::LimitTripped { joint, side, .. } if s.mask == Some((joint, side)) => {
                    event = SwitchEvent::LimitMasked { joint, side };
                    false
                }
                SwitchEvent::LimitTripped { .. } => true,
                _ => false,
            };
            if halts {
                s.halting = true;
                if s.first_trip.is_none() {
                    s.first_trip = Some(event);
                    return Some((event, true));
                }
            }
            // A full queue drops the event (never the first trip, kept above).
            let _ = s.events.push_back(event);
            Some((event, halts))
        });
        if let Some((_, halts)) = event {
            if halts {
                step.halt();
                kick.kick();
            }
            wake.signal(());
        }
    }

    /// The releases whose debounce time has passed by `now_us` are queued (the task
    /// calls it with its clock before [`Self::take`]).
    pub fn poll(&self, now_us: u64) {
        self.state.lock(|s| {
            let mut s = s.borrow_mut();
            while let Some(e) = s.bank.poll(now_us) {
                let _ = s.events.push_back(e);
            }
        });
    }

    /// The next event for the controller: the first trip first, then the queue in order.
    pub fn take(&self) -> Option<SwitchEvent> {
        self.state.lock(|s| {
            let mut s = s.borrow_mut();
            s.first_trip.take().or_else(|| s.events.pop_front())
        })
    }

    /// After the controller has taken the trips: lifts this line's halt, unless the wired
    /// e-stop input (`estop`) is open (its own halt stays until it closes). Checked and
    /// lifted under the input's lock, so an opening cannot slip in between.
    pub fn resume<
        const Q: usize,
        B: StepBackend,
        M: embassy_sync::blocking_mutex::raw::RawMutex,
    >(
        &self,
        step: &StepShared<Q, B, M>,
        estop: Option<&EStopLine>,
    ) {
        // A trip that came after the last take keeps its halt for the next look.
        let lift = self.state.lock(|s| {
            let mut s = s.borrow_mut();
            if s.first_trip.is_some() {
                return false;
            }
            core::mem::replace(&mut s.halting, false)
        });
        if !lift {
            return;
        }
        match estop {
            Some(line) => line.release_unless_open(step),
            None => step.release(),
        }
    }
}
