//! The board's wired e-stop input, simulated (`--estop-input`; issue 18 part 3).
//!
//! A normally-closed input, closed at start. Whoever changes it plays the board's EXTI
//! interrupt: [`SimEStopInput::open`] stops the step outputs right there, in the calling
//! thread ([`arm_core::EStopLine::edge`]: the shared step backend's emergency stop, which
//! plays the edges up to that instant and cuts the rest, then a kick of the step thread),
//! before any task runs, and cuts a gripper burst (a servo PWM only with `--servo-on-stop
//! cut`) as the board's interrupt does (issue 30); then the trajectory task, woken, puts
//! the controller in STOPPED
//! and latches it (RUNING and RETURN refused `ESTOP_LATCHED` until the input is closed and
//! a host sends ESTOP_RESET).
//!
//! Who changes it: in-process, the [`crate::app::Board`]'s `estop_input` (tests of this
//! crate); from outside, signals to the sim-host process: SIGUSR1 opens the input,
//! SIGUSR2 closes it ([`Signals`], installed before the address line is printed). The
//! VCD trace has the input as the `estop_input` wire (1 = open), stamped when the input
//! changes, before the stop: the time from its rise to the last STEP edge is the
//! simulated stop latency.

use std::io;
use std::sync::{Arc, Mutex, OnceLock};

use arm_core::EStopLine;
use arm_core::bus::Cs;
use embassy_sync::signal::Signal as Wake;
use signal_hook::consts::{SIGUSR1, SIGUSR2};

use arm_core::config::ServoOnStop;

use crate::app::SimStepShared;
use crate::devices::SimGripper;
use crate::steptimer::SimStepKick;
use crate::vcd::{Signal, Tracer, Value};

/// The input's state, shared with the trajectory task (one simulated controller per
/// process, as the bus).
pub static LINE: EStopLine = EStopLine::new();

/// What the input's edge acts on, known once the tasks are wired.
struct Wired {
    step: &'static SimStepShared,
    wake: &'static Wake<Cs, ()>,
}

/// The simulated input ([`crate::app::Board::estop_input`]).
pub struct SimEStopInput {
    wired: OnceLock<Wired>,
    kick: SimStepKick,
    tracer: Tracer,
    /// The gripper timer, cut at the edge as the board's EXTI0 cuts TIM15.
    gripper: SimGripper,
    /// Whether that cut includes a servo PWM.
    servo_on_stop: ServoOnStop,
    /// Serialises changes from several threads (a test and the signal thread).
    changing: Mutex<()>,
}

impl std::fmt::Debug for SimEStopInput {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SimEStopInput")
            .field("open", &self.is_open())
            .finish()
    }
}

impl SimEStopInput {
    /// A closed input that kicks `kick`'s step thread, cuts `gripper` (a servo PWM too
    /// under [`ServoOnStop::Cut`]) and traces into `tracer`.
    pub fn new(
        kick: SimStepKick,
        tracer: Tracer,
        gripper: SimGripper,
        servo_on_stop: ServoOnStop,
    ) -> SimEStopInput {
        tracer.record(Signal::EStopInput, Value::Bit(false));
        SimEStopInput {
            wired: OnceLock::new(),
            kick,
            tracer,
            gripper,
            servo_on_stop,
            changing: Mutex::new(()),
        }
    }

    /// Connects the input to the shared step backend and the trajectory task's wake-up
    /// (the bus's `step_progress`); done by the app when it wires the tasks.
    pub fn wire(&self, step: &'static SimStepShared, wake: &'static Wake<Cs, ()>) {
        let _ = self.wired.set(Wired { step, wake });
    }

    /// Opens the input (the e-stop button pressed, or its wire cut): when this returns,
    /// no STEP edge follows.
    pub fn open(&self) {
        self.set(true);
    }

    /// Closes the input again (the latch stays until a host sends ESTOP_RESET).
    pub fn close(&self) {
        self.set(false);
    }

    /// Whether the input is open.
    pub fn is_open(&self) -> bool {
        LINE.is_open()
    }

    fn set(&self, open: bool) {
        let _changing = self.changing.lock();
        self.tracer.record(Signal::EStopInput, Value::Bit(open));
        match self.wired.get() {
            Some(w) => {
                LINE.edge(open, w.step, &self.kick, w.wake);
                if open {
                    self.gripper.cut_at_stop(self.servo_on_stop);
                }
            }
            None => log::warn!("e-stop input changed before the controller was wired: ignored"),
        }
        if open {
            log::warn!(
                "e-stop input open: step outputs and gripper burst stopped, controller latched"
            );
        } else {
            log::warn!("e-stop input closed: ESTOP_RESET clears the latch");
        }
    }
}

/// The signals that change the input from outside (SIGUSR1 opens, SIGUSR2 closes), caught
/// from now on (before the simulator says where it listens, so that a test that signals
/// it as soon as it can never kills it).
pub struct Signals(signal_hook::iterator::Signals);

impl Signals {
    /// Installs the handlers.
    pub fn catch() -> io::Result<Signals> {
        Ok(Signals(signal_hook::iterator::Signals::new([
            SIGUSR1, SIGUSR2,
        ])?))
    }

    /// Applies every signal caught (also those caught before) to `input`, on a thread of
    /// its own: the thread that sees the edge stops the steps.
    pub fn apply_to(mut self, input: Arc<SimEStopInput>) -> io::Result<()> {
        std::thread::Builder::new()
            .name("estop-input".into())
            .spawn(move || {
                for signal in self.0.forever() {
                    match signal {
                        SIGUSR1 => input.open(),
                        SIGUSR2 => input.close(),
                        _ => {}
                    }
                }
            })?;
        Ok(())
    }
}
