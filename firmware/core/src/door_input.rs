//! The safety-door input (issue 32): a contact whose opening holds the run (a controlled
//! stop along the path, [`crate::Controller::door_input`]), not an emergency stop: it
//! halts nothing in the handler, it only records the level and wakes the trajectory task,
//! which applies it before anything else it handles (as the e-stop line's
//! [`crate::EStopLine::take`]). An opening is never lost: [`DoorSample::opened`] stays set
//! until the task takes it, so a door opened and closed again before the task ran still
//! holds the run (a RESUME goes on).
//!
//! The simulator drives it ([`DoorLine::set`] from `VirtualBoard::set_door`); the NUCLEO's
//! pin is chosen in docs/BOARD.md and not wired yet. A board without the input passes no
//! line to the trajectory task: the door reads closed.

use core::cell::Cell;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::signal::Signal;

use crate::bus::Cs;

/// What the trajectory task learns from the door ([`DoorLine::take`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DoorSample {
    /// The door is open now.
    pub open: bool,
    /// It opened at least once since the last [`DoorLine::take`].
    pub opened: bool,
}

/// The door input as its handler and the trajectory task share it. Put one in a `static`
/// (`new` is `const`).
pub struct DoorLine {
    state: Mutex<Cs, Cell<DoorSample>>,
}

impl Default for DoorLine {
    fn default() -> Self {
        Self::new()
    }
}

impl DoorLine {
    /// Closed, nothing to take.
    pub const fn new() -> Self {
        DoorLine {
            state: Mutex::new(Cell::new(DoorSample {
                open: false,
                opened: false,
            })),
        }
    }

    /// The door is now `open` (or closed): records it and wakes the trajectory task
    /// (`bus.step_progress`, which it always waits on).
    pub fn set(&self, open: bool, wake: &Signal<Cs, ()>) {
        self.state.lock(|s| {
            let mut v = s.get();
            v.open = open;
            v.opened |= open;
            s.set(v);
        });
        wake.signal(());
    }

    /// Whether the door is open now.
    pub fn is_open(&self) -> bool {
        self.state.lock(|s| s.get().open)
    }

    /// The level now and whether it opened since the last take (cleared).
    pub fn take(&self) -> DoorSample {
        self.state.lock(|s| {
            let v = s.get();
            s.set(DoorSample {
                open: v.open,
                opened: false,
            });
            v
        })
    }
}
