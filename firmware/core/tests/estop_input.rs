//! Issue 18 part 3, the wired e-stop input (docs/PROTOCOL.md sections 4, 5 and 8;
//! `arm_core::estop_input`): opening it stops the step backend in the edge handler itself,
//! before any task runs; the controller then goes to STOPPED and latches, refuses RUNING
//! and RETURN with ESTOP_LATCHED until the input is closed and ESTOP_RESET clears the
//! latch; STATUS shows the input and the latch. Sans-io on virtual time, and the step
//! backend shared with the interrupts without any task.

mod common;

use std::cell::Cell;

use arm_core::bus::Cs;
use arm_core::hw::StepKick;
use arm_core::{EStopLine, EStopSample, StepShared};
use arm_step::{Segment, StepTiming};
use common::*;
use embassy_sync::signal::Signal;
use protocol::{Command, MAX_JOINTS, MoreFlags, State, StatusCode, StatusFlags};

fn more_flags(s: &Session<64>) -> MoreFlags {
    s.controller.status(&s.plant).more_flags
}

#[test]
fn opening_the_input_stops_a_run_and_latches() {
    let mut s = Session::<64>::new(64);
    s.start_endless_run();
    let stops = s.plant.stops;
    let location = s.controller.estop_input(true, &mut s.plant);
    assert!(s.plant.stops > stops, "the engine was stopped");
    assert!(!s.plant.running);
    assert_eq!(s.controller.state(), State::Stopped);
    assert_eq!(s.controller.buffered(), 0, "the trajectory is dropped");
    let location = location.expect("a LOCATION of the state change");
    assert_eq!(location.state, State::Stopped as u8);
    let status = s.controller.status(&s.plant);
    assert!(status.flags.has(StatusFlags::STOPPED_BY_HOST), "bit 7");
    assert!(!status.flags.has(StatusFlags::UNDERRUN));
    assert!(status.more_flags.has(MoreFlags::ESTOP_OPEN));
    assert!(status.more_flags.has(MoreFlags::ESTOP_LATCHED));
    assert!(s.controller.estop_latched());
    // Nothing moves afterwards: the segments handed over are gone.
    assert_eq!(s.plant.run(&mut s.controller, 10), None);
    assert!(s.plant.queue.is_empty());
}

#[test]
fn opening_drops_an_upload_not_yet_running() {
    let mut s = Session::<64>::new(64);
    s.expect(Command::New { count: 20 }, StatusCode::Ok);
    s.pending(&points([0; MAX_JOINTS], 12, 1));
    assert_eq!(s.controller.state(), State::Pending);
    s.controller.estop_input(true, &mut s.plant);
    assert_eq!(s.controller.state(), State::Stopped);
    assert_eq!(s.controller.buffered(), 0);
    s.expect(Command::Runing, StatusCode::EstopLatched);
}

#[test]
fn the_latch_refuses_runing_and_return_until_closed_and_reset() {
    let mut s = Session::<64>::new(64);
    s.start_endless_run();
    s.controller.estop_input(true, &mut s.plant);
    // Open: an upload is taken, but it cannot run, however often the host asks.
    s.expect(Command::New { count: 12 }, StatusCode::Ok);
    s.pending(&points(s.plant.positions, 12, 1));
    for attempt in 0..5 {
        let ack = s.expect(Command::Runing, StatusCode::EstopLatched);
        assert_eq!(ack.state, State::Pending, "attempt {attempt}");
        assert!(!s.plant.running, "attempt {attempt}");
    }
    s.expect(Command::Stopped, StatusCode::Ok);
    let ack = s.expect(Command::Return, StatusCode::EstopLatched);
    assert_eq!(ack.state, State::Stopped, "old hosts see STOPPED");
    // ESTOP_RESET while the input is open: refused, the latch stays.
    s.expect(Command::EstopReset, StatusCode::EstopLatched);
    assert!(s.controller.estop_latched());
    // Closed but not reset: still latched.
    s.controller.estop_input(false, &mut s.plant);
    let flags = more_flags(&s);
    assert!(!flags.has(MoreFlags::ESTOP_OPEN));
    assert!(flags.has(MoreFlags::ESTOP_LATCHED));
    s.expect(Command::New { count: 12 }, StatusCode::Ok);
    s.pending(&points(s.plant.positions, 12, 1));
    for _ in 0..3 {
        s.expect(Command::Runing, StatusCode::EstopLatched);
    }
    s.expect(Command::Stopped, StatusCode::Ok);
    s.expect(Command::Return, StatusCode::EstopLatched);
    assert_eq!(s.plant.starts, 1, "only the first run ever started");
    // Closed and reset: runs again.
    s.expect(Command::EstopReset, StatusCode::Ok);
    assert!(!s.controller.estop_latched());
    assert_eq!(
        more_flags(&s).0 & (MoreFlags::ESTOP_OPEN | MoreFlags::ESTOP_LATCHED),
        0
    );
    s.start_endless_run();
    assert_eq!(s.plant.starts, 2);
    s.expect(Command::Stopped, StatusCode::Ok);
    s.expect(Command::Return, StatusCode::Ok);
}

#[test]
fn an_input_that_opened_and_closed_still_latches() {
    // The task applies every opening it finds (EStopSample::opened), then the level.
    let mut s = Session::<64>::new(64);
    s.start_endless_run();
    s.controller.estop_input(true, &mut s.plant);
    s.controller.estop_input(false, &mut s.plant);
    assert_eq!(s.controller.state(), State::Stopped);
    assert!(s.controller.estop_latched());
    s.expect(Command::New { count: 12 }, StatusCode::Ok);
    s.pending(&points(s.plant.positions, 12, 1));
    s.expect(Command::Runing, StatusCode::EstopLatched);
}

#[test]
fn estop_reset_without_a_latch_is_ok_and_changes_nothing() {
    let mut s = Session::<64>::new(64);
    let before = s.controller.status(&s.plant);
    let ack = s.expect(Command::EstopReset, StatusCode::Ok);
    assert_eq!(ack.state, State::Stopped);
    assert_eq!(s.controller.status(&s.plant), before);
    // During a run too: the run goes on.
    s.start_endless_run();
    s.expect(Command::EstopReset, StatusCode::Ok);
    assert_eq!(s.controller.state(), State::Running);
    assert!(s.plant.running);
}

#[test]
fn estop_reset_is_the_owners_like_other_commands() {
    let mut s = Session::<64>::new(64);
    s.expect(Command::Status, StatusCode::Ok);
    s.controller.estop_input(true, &mut s.plant);
    s.controller.estop_input(false, &mut s.plant);
    s.from = OTHER;
    s.expect(Command::EstopReset, StatusCode::NotOwner);
    assert!(s.controller.estop_latched());
    s.from = HOST;
    s.expect(Command::EstopReset, StatusCode::Ok);
    assert!(!s.controller.estop_latched());
}

#[test]
fn an_input_opened_during_returns_encoder_read_stops_it_before_it_moves() {
    let mut s = Session::<64>::new(64);
    s.set_location([500; MAX_JOINTS]);
    s.expect(Command::Return, StatusCode::Ok);
    assert_eq!(s.controller.state(), State::Running);
    // The trajectory task applies the input after the read, before begin_return.
    s.controller.estop_input(true, &mut s.plant);
    assert_eq!(s.controller.state(), State::Stopped);
    assert_eq!(s.controller.begin_return(None, &mut s.plant), None);
    assert_eq!(s.controller.state(), State::Stopped);
    assert_eq!(s.plant.starts, 0, "RETURN never started");
    assert!(s.plant.queue.is_empty());
}

#[test]
fn closing_alone_changes_no_state() {
    let mut s = Session::<64>::new(64);
    s.start_endless_run();
    assert_eq!(s.controller.estop_input(false, &mut s.plant), None);
    assert_eq!(s.controller.state(), State::Running);
    assert!(!s.controller.estop_latched());
}

// --- The edge handler's half: the step backend, no task. ---

const TIMING: StepTiming = StepTiming {
    tick_hz: 1_000_000,
    pulse_width_ticks: 2,
    dir_setup_ticks: 1,
    step_low_ticks: 1,
};

/// A step timer whose kicks are counted.
#[derive(Default)]
struct Kick {
    kicks: Cell<u32>,
}

impl StepKick for Kick {
    fn kick(&self) {
        self.kicks.set(self.kicks.get() + 1);
    }
    fn now_tick(&self) -> u64 {
        0
    }
}

/// The trajectory task's wake-up (the bus's `step_progress`).
type Wake = Signal<Cs, ()>;

/// A shared engine running one long segment.
fn running_engine() -> StepShared<8> {
    let step = StepShared::<8>::new(TIMING);
    let segment = Segment {
        duration_us: 1_000_000,
        steps: [1_000, 0, 0, 0, 0, 0, 0, 0],
    };
    step.with_engine(|e| {
        e.push(segment).unwrap();
        e.start(10);
    });
    assert!(step.with_engine(|e| e.is_running()));
    step
}

#[test]
fn the_edge_handler_stops_the_engine_itself_without_any_task() {
    let step = running_engine();
    let kick = Kick::default();
    let line = EStopLine::new();
    let wake = Wake::new();
    line.edge(true, &step, &kick, &wake);
    // Stopped when `edge` returns: no task ran, nothing was awaited.
    assert!(!step.with_engine(|e| e.is_running()));
    assert_eq!(step.with_engine(|e| e.queued()), 0);
    assert_eq!(kick.kicks.get(), 1, "the step interrupt lowers the lines");
    assert!(line.is_open());
    assert!(wake.signaled(), "the trajectory task is woken");
    // The trajectory task, still feeding the stopped run until it takes the opening,
    // pushes another of its segments: it is held, never started (issue 19: there is no
    // relay left whose stale segments needed a stop count).
    let late = Segment {
        duration_us: 1_000,
        steps: [10, 0, 0, 0, 0, 0, 0, 0],
    };
    assert!(step.push(late, 100));
    assert!(
        !step.with_engine(|e| e.is_running()),
        "a late segment runs nothing"
    );
}

#[test]
fn no_run_starts_while_the_input_is_open() {
    let step = StepShared::<8>::new(TIMING);
    let kick = Kick::default();
    let line = EStopLine::new();
    let wake = Wake::new();
    line.edge(true, &step, &kick, &wake);
    // A RUNING the trajectory task was handling when the input opened.
    let segment = Segment {
        duration_us: 1_000,
        steps: [10, 0, 0, 0, 0, 0, 0, 0],
    };
    step.with_engine(|e| e.push(segment).unwrap());
    step.start(100);
    assert!(!step.with_engine(|e| e.is_running()), "halted: no start");
    line.edge(false, &step, &kick, &wake);
    step.start(100);
    assert!(step.with_engine(|e| e.is_running()), "released: starts");
}

#[test]
fn an_opening_is_kept_until_the_task_takes_it() {
    let step = StepShared::<8>::new(TIMING);
    let kick = Kick::default();
    let line = EStopLine::new();
    let wake = Wake::new();
    assert_eq!(line.take(), EStopSample::default());
    line.edge(true, &step, &kick, &wake);
    line.edge(false, &step, &kick, &wake);
    assert_eq!(
        line.take(),
        EStopSample {
            open: false,
            opened: true,
            controlled: false,
        },
        "opened and closed before the task looked"
    );
    assert_eq!(line.take(), EStopSample::default(), "taken once");
    line.edge(true, &step, &kick, &wake);
    assert_eq!(
        line.take(),
        EStopSample {
            open: true,
            opened: true,
            controlled: false,
        }
    );
    assert_eq!(
        line.take(),
        EStopSample {
            open: true,
            opened: false,
            controlled: false,
        }
    );
}
