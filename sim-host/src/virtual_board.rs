//! The simulated controller on virtual time, in the test's own thread (issue 19): the same
//! firmware tasks (`arm_core::controller_task` and `network_task`), the same simulated
//! hardware (the step streams played by arm-step's `StreamPlayer`, the gripper, the
//! settings file, the encoders, the VCD trace), but no threads, no socket and no wall
//! clock. Simulated time stands still until [`VirtualBoard::run_for`] moves it, one
//! [`QUANTUM_NS`] per round; each round polls the tasks until they wait, then plays the
//! step hardware if a refill, the run's end or a kick is due. A loaded machine makes a
//! test slower, never different.
//!
//! Datagrams go in with [`VirtualBoard::send`] and come out in [`VirtualBoard::sent`]; the
//! host side is the test's own code. What must stay on real time (the UDP socket, the
//! kernel, the step thread's wake-ups) is what the process tests in `tests/` cover.

use std::cell::RefCell;
use std::collections::VecDeque;
use std::future::Future;
use std::path::Path;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll, Waker};

use arm_core::hw::{Datagrams, Endpoint};
use arm_core::{Bus, Controller, DoorLine, EStopLine, StepShared, TrajectoryHw};

use crate::app::{Board, STEP_QUEUE, controller_config, step_timing};
use crate::clock::SimClock;
use crate::options::SimOptions;
use crate::steppers::MotorState;
use crate::steptimer::{SimStepKick, SimSteps};
use crate::vcd::Tracer;

/// Simulated time per round: the finest a task's timer or a refill is late by. 10 us is
/// far below every period the tests look at (LOCATION 10 ms, a 100 kHz step 10 us is
/// timed by the streams themselves, to the tick).
pub const QUANTUM_NS: u64 = 10_000;

/// Polls of the tasks per round before the round gives up waiting for them to settle
/// (they never wait on anything but time and datagrams, so a few polls settle them).
const POLLS_PER_ROUND: usize = 8;

/// Trajectory points of the virtual controller: enough for the tests, small enough to
/// build on a test thread's stack.
pub const VIRTUAL_CAPACITY: usize = 1024;

/// The datagrams in and out.
#[derive(Default)]
pub struct VirtualSocket {
    incoming: RefCell<VecDeque<(Vec<u8>, Endpoint)>>,
    outgoing: RefCell<Vec<(Endpoint, Vec<u8>)>>,
}

impl Datagrams for VirtualSocket {
    type Error = ();
    fn recv(&self, buf: &mut [u8]) -> impl Future<Output = Result<(usize, Endpoint), ()>> {
        std::future::poll_fn(move |cx| match self.incoming.borrow_mut().pop_front() {
            Some((bytes, from)) => {
                let n = bytes.len().min(buf.len());
                buf[..n].copy_from_slice(&bytes[..n]);
                Poll::Ready(Ok((n, from)))
            }
            None => {
                cx.waker().wake_by_ref();
                Poll::Pending
            }
        })
    }
    fn send(&self, to: Endpoint, frame: &[u8]) -> impl Future<Output = Result<(), ()>> {
        self.outgoing.borrow_mut().push((to, frame.to_vec()));
        std::future::ready(Ok(()))
    }
}

type VirtualSteps = StepShared<STEP_QUEUE, SimSteps<STEP_QUEUE>>;

/// One simulated controller on virtual time.
pub struct VirtualBoard {
    /// Its clock (virtual).
    pub clock: SimClock,
    /// The motors the STEP/DIR lines move.
    pub motors: Arc<MotorState>,
    /// The VCD trace (disabled unless built with one).
    pub tracer: Tracer,
    socket: &'static VirtualSocket,
    bus: &'static Bus,
    step: &'static VirtualSteps,
    kick: &'static SimStepKick,
    /// The safety-door input (issue 32): [`VirtualBoard::set_door`].
    door: &'static DoorLine,
    /// The wired e-stop input (issue 18; its category, issue 32):
    /// [`VirtualBoard::set_estop_input`]. A line of this board's own, not
    /// `crate::estop::LINE`: tests run several boards in one process.
    estop: &'static EStopLine,
    tasks: Pin<Box<dyn Future<Output = ()>>>,
}

impl VirtualBoard {
    /// Builds the controller as `sim-host` would with `options` (its `--tick-hz`,
    /// `--joints`, `--buffer-capacity`, encoders and settings file), tracing to `trace`
    /// if given, on a virtual clock at 0.
    pub fn new(options: &SimOptions, trace: Option<&Path>) -> std::io::Result<VirtualBoard> {
        // The simulator's own board (app.rs), on a virtual clock and without a socket.
        let mut options = options.clone();
        options.trace = trace.map(Path::to_path_buf);
        options.pcap = None;
        let board = Board::build_on(&options, SimClock::virtual_time(options.tick_hz), false)?;
        let clock = board.clock;
        let timing = step_timing(options.tick_hz);
        let step: &'static VirtualSteps = Box::leak(Box::new(StepShared::with_backend(
            SimSteps::new(timing, board.step_pins(), clock),
        )));
        let bus: &'static Bus = Box::leak(Box::new(Bus::new()));
        let door: &'static DoorLine = Box::leak(Box::new(DoorLine::new()));
        let estop: &'static EStopLine = Box::leak(Box::new(EStopLine::new()));
        let socket: &'static VirtualSocket = Box::leak(Box::default());
        let kick: &'static SimStepKick = Box::leak(Box::new(board.kick.clone()));
        let clock_ref: &'static SimClock = Box::leak(Box::new(clock));
        let config = arm_core::ControllerConfig {
            capacity: controller_config(&options).capacity.min(VIRTUAL_CAPACITY),
            ..controller_config(&options)
        };
        let controller: &'static mut Controller<VIRTUAL_CAPACITY> =
            Box::leak(Box::new(Controller::new(config)));
        let mut settings = board.settings.clone();
        settings.set_boot_joints(options.joints);
        let hw = TrajectoryHw {
            kick,
            outputs: board.outputs(),
            gripper: board.gripper.clone(),
            serial: board.serial,
            settings,
            encoders: board.encoders.clone(),
            estop: Some(estop),
            door: Some(door),
            switches: None,
        };
        let (motors, tracer) = (board.motors.clone(), board.tracer.clone());
        let tasks = async move {
            let controller = arm_core::controller_task(
                controller,
                bus,
                step,
                clock_ref,
                hw,
                &arm_core::Unwatched,
            );
            let network = arm_core::tasks::network_task(socket, bus, clock_ref);
            let _ = embassy_futures::select::select(controller, network).await;
        };
        Ok(VirtualBoard {
            clock,
            motors,
            tracer,
            socket,
            bus,
            step,
            kick,
            door,
            estop,
            tasks: Box::pin(tasks),
        })
    }

    /// Opens or closes the safety door (issue 32): the trajectory task applies it in the
    /// next round (opening holds the run; closing and a RESUME go on).
    pub fn set_door(&self, open: bool) {
        self.door.set(open, &self.bus.step_progress);
    }

    /// Opens or closes the wired e-stop input, as `--estop-input`'s signals do
    /// ([`crate::estop::SimEStopInput`]: the edge handler's work right here, before any
    /// task runs: category 0 halts the steps at once, category 1 leaves a run to the
    /// controlled stop; the trajectory task applies it in the next round). Traced as the
    /// `estop_input` wire.
    pub fn set_estop_input(&self, open: bool) {
        self.tracer
            .record(crate::vcd::Signal::EStopInput, crate::vcd::Value::Bit(open));
        self.estop
            .edge(open, self.step, self.kick, &self.bus.step_progress);
    }

    /// Delivers a datagram from `from` (read by the network task in the next round).
    pub fn send(&self, from: Endpoint, bytes: &[u8]) {
        self.socket
            .incoming
            .borrow_mut()
            .push_back((bytes.to_vec(), from));
    }

    /// Takes every datagram the controller sent so far, with its destination.
    pub fn sent(&self) -> Vec<(Endpoint, Vec<u8>)> {
        std::mem::take(&mut *self.socket.outgoing.borrow_mut())
    }

    /// Runs the controller for `ns` of simulated time.
    pub fn run_for(&mut self, ns: u64) {
        let end = self.clock.now_ns() + ns;
        while self.clock.now_ns() < end {
            self.round();
            self.clock
                .advance_ns(QUANTUM_NS.min(end - self.clock.now_ns()));
        }
        self.round();
    }

    /// Runs rounds until `done` holds, at most `limit_ns` of simulated time; whether it
    /// held.
    pub fn run_until(&mut self, limit_ns: u64, mut done: impl FnMut(&mut Self) -> bool) -> bool {
        let end = self.clock.now_ns() + limit_ns;
        loop {
            self.round();
            if done(self) {
                return true;
            }
            if self.clock.now_ns() >= end {
                return false;
            }
            self.clock.advance_ns(QUANTUM_NS);
        }
    }

    /// One round at the current time: the tasks until they wait, then the step hardware
    /// (a refill, the run's end, or a kick), then the tasks again for what it signalled.
    fn round(&mut self) {
        self.poll_tasks();
        let now = self.clock.now_tick();
        let kicked = self.kick.take_kick();
        let due = self
            .step
            .with_engine(|steps| steps.next_due())
            .is_some_and(|d| d <= now);
        if kicked || due {
            self.step
                .on_interrupt(&self.bus.step_progress, |steps| ((), steps.advance(now)));
            self.poll_tasks();
        }
    }

    fn poll_tasks(&mut self) {
        let mut cx = Context::from_waker(Waker::noop());
        for _ in 0..POLLS_PER_ROUND {
            if self.tasks.as_mut().poll(&mut cx).is_ready() {
                panic!("the controller's tasks ended");
            }
        }
    }

    /// Flushes the VCD trace (read it with `armctl::vcd::read_changes` afterwards).
    pub fn finish_trace(&self) {
        self.tracer.finish();
    }
}
