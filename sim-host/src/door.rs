//! The safety-door input, simulated (`--door-input`; issue 32): the NUCLEO's PF4 (docs/
//! BOARD.md), closed at start. Opening it holds a run (a controlled stop along its path,
//! HOLD's ramp; the controller's [`arm_core::Controller::door_input`]); while it is open
//! RUNING and RESUME are refused `DOOR_OPEN`; closing it and a RESUME go on.
//!
//! Unlike the e-stop input ([`crate::estop`]) the handler halts nothing: it records the
//! level in the shared [`arm_core::DoorLine`] and wakes the trajectory task, which applies
//! it before anything else it handles.
//!
//! Who changes it: in-process, the [`crate::app::Board`]'s `door_input` (and
//! `VirtualBoard::set_door` on virtual time); from outside, real-time signals to the
//! sim-host process (SIGUSR1/SIGUSR2 are the e-stop input's): SIGRTMIN+1 opens the door,
//! SIGRTMIN+2 closes it (`kill -s RTMIN+1 PID` / `kill -s RTMIN+2 PID`), caught before
//! the address line is printed ([`Signals`]). The VCD trace has it as the `door_input`
//! wire (1 = open).

use std::io;
use std::sync::{Arc, OnceLock};

use arm_core::DoorLine;
use arm_core::bus::Cs;
use embassy_sync::signal::Signal as Wake;

use crate::vcd::{Signal, Tracer, Value};

/// The input's state, shared with the trajectory task (one simulated controller per
/// process, as the bus).
pub static LINE: DoorLine = DoorLine::new();

/// The signal that opens the door: SIGRTMIN+1 (glibc's own use of the first real-time
/// signals is below `libc::SIGRTMIN()`, which already leaves them out).
pub fn open_signal() -> i32 {
    libc::SIGRTMIN() + 1
}

/// The signal that closes it: SIGRTMIN+2.
pub fn close_signal() -> i32 {
    libc::SIGRTMIN() + 2
}

/// The simulated door input ([`crate::app::Board::door_input`]).
pub struct SimDoorInput {
    wake: OnceLock<&'static Wake<Cs, ()>>,
    tracer: Tracer,
}

impl std::fmt::Debug for SimDoorInput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimDoorInput")
            .field("open", &self.is_open())
            .finish()
    }
}

impl SimDoorInput {
    /// A closed door traced into `tracer`.
    pub fn new(tracer: Tracer) -> SimDoorInput {
        tracer.record(Signal::DoorInput, Value::Bit(false));
        SimDoorInput {
            wake: OnceLock::new(),
            tracer,
        }
    }

    /// Connects the input to the trajectory task's wake-up (the bus's `step_progress`);
    /// done by the app when it wires the tasks.
    pub fn wire(&self, wake: &'static Wake<Cs, ()>) {
        let _ = self.wake.set(wake);
    }

    /// Opens the door: a run holds.
    pub fn open(&self) {
        self.set(true);
    }

    /// Closes it (a host RESUMEs a held run).
    pub fn close(&self) {
        self.set(false);
    }

    /// Whether the door is open.
    pub fn is_open(&self) -> bool {
        LINE.is_open()
    }

    fn set(&self, open: bool) {
        self.tracer.record(Signal::DoorInput, Value::Bit(open));
        match self.wake.get() {
            Some(wake) => LINE.set(open, wake),
            None => log::warn!("door input changed before the controller was wired: ignored"),
        }
        if open {
            log::warn!("door input open: a run holds; RUNING and RESUME refused DOOR_OPEN");
        } else {
            log::warn!("door input closed: RESUME goes on");
        }
    }
}

/// The signals that change the door from outside (SIGRTMIN+1 opens, SIGRTMIN+2 closes),
/// caught from now on.
pub struct Signals(signal_hook::iterator::Signals);

impl Signals {
    /// Installs the handlers.
    pub fn catch() -> io::Result<Signals> {
        Ok(Signals(signal_hook::iterator::Signals::new([
            open_signal(),
            close_signal(),
        ])?))
    }

    /// Applies every signal caught (also those caught before) to `input`, on a thread of
    /// its own.
    pub fn apply_to(mut self, input: Arc<SimDoorInput>) -> io::Result<()> {
        std::thread::Builder::new()
            .name("door-input".into())
            .spawn(move || {
                for signal in self.0.forever() {
                    if signal == open_signal() {
                        input.open();
                    } else if signal == close_signal() {
                        input.close();
                    }
                }
            })?;
        Ok(())
    }
}
