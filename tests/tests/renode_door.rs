//! Issue 32's safety door on the NUCLEO-H743ZI2 firmware itself (the `cargo fw --features
//! door-input` ELF) on Renode, with the step path's models and edge recorder (as
//! `renode_switches.rs`). PF4 is a GPIO input the test drives from Renode's monitor
//! (`sysbus.gpioPortF OnGPIO 4 true`: the STM32 GPIO model, SYSCFG's EXTI routing, EXTI
//! line 4 and the NVIC are Renode's own); the recorder watches it too, so the door's edge
//! and every STEP edge are on one virtual clock (ns).
//!
//! The board's step side has the time warp (issue 32), so an open door holds the run along
//! its path (PROTOCOL.md, "Safety door"): no STEP edge past the hold's bound after PF4 went
//! high (the latency is printed), MOTION shows the door open and the run held at rest;
//! RESUME and RUNING are refused `DOOR_OPEN` while it is; closed, RESUME ends the run exact.
//!
//! Needs Renode and root, as `renode_steps.rs`; without them the test prints what it needs
//! and passes.

mod common;

use std::sync::Arc;
use std::time::Duration;

use common::run_reporting_progress_with;
use protocol::{
    Command, ControlledStop, MAX_JOINTS, MotionFlags, Point, State, StatusCode, StopCause,
};
use system_tests::renode::emulated;
use system_tests::renode::{HOSTS, RenodeBoard, unavailable};

/// The recorder's input for the door pin (PF4).
const DOOR: u8 = 42;

/// The recorder watches the door pin too.
const WATCH_DOOR: &str = "sysbus.stepRecorder Watch \"sysbus.gpioPortF\" 4 42";

fn note(text: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr().lock(), "renode door: {text}");
}

/// Points of 10 ms from `start`, joint 0 `step` further each.
fn points(start: [i32; MAX_JOINTS], n: i32, step: i32) -> Vec<Point> {
    let mut previous = start;
    (1..=n)
        .map(|i| {
            let mut target = start;
            target[0] += step * i;
            let point = Point::from_motion(10_000, &previous, &target);
            previous = target;
            point
        })
        .collect()
}

/// When the input `line` (the recorder's, named `pin`) first went high, and the last STEP
/// edge of any joint, ns of virtual time.
fn opened_and_last_step(
    board: &RenodeBoard,
    edges: &[system_tests::renode::Edge],
    line: u8,
    pin: &str,
) -> (u64, u64) {
    let opened = edges
        .iter()
        .find(|e| e.line == line && e.high)
        .unwrap_or_else(|| panic!("the recorder saw {pin} go high\n{}", board.log()))
        .ns;
    let last_step = edges
        .iter()
        .filter(|e| e.line < 8)
        .map(|e| e.ns)
        .max()
        .expect("STEP edges");
    (opened, last_step)
}

fn motion_flags(arm: &armctl::Client) -> u8 {
    arm.motion()
        .ok()
        .and_then(|(_, m)| m)
        .map_or(0, |m| m.flags.0)
}

/// The most a STEP edge may come after the door opened: the hold's ramp (no ACCEL_SET:
/// arm-core's `UNLIMITED_RAMP`, a full swing in 0.25 s), the producer's write-ahead a
/// change waits for (PROTOCOL.md, HOLD: about 42 ms at most), one step period (2.5 ms) and
/// 20 ms of the trajectory task's own latency; virtual time, so a slower machine changes
/// nothing.
const HOLD_BOUND_NS: u64 = 250_000_000 + 42_000_000 + 2_500_000 + 20_000_000;

/// The run's options: the hold lasts as long as the test takes to see it at rest and to
/// close the door (seconds of wall time); generous so that only a real stall fails.
fn held_run_options() -> armctl::RunOptions {
    armctl::RunOptions {
        stall_timeout: Duration::from_secs(60),
        completion_timeout: Some(Duration::from_secs(600)),
        ..armctl::RunOptions::default()
    }
}

/// Polls MOTION until `flags` are all set (bounded).
fn wait_motion(board: &RenodeBoard, arm: &armctl::Client, flags: u8, what: &str) {
    let deadline = std::time::Instant::now() + Duration::from_secs(120);
    while motion_flags(arm) & flags != flags {
        assert!(
            std::time::Instant::now() < deadline,
            "{what}: not within 120 s\n{}",
            board.log()
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Issue 32's door on the board with the warp (the board holds since issue 32's board
/// work; before it, the step side could not hold and the door stopped the run: this test
/// checked that, and changed with the rule): opening PF4 holds the run along its path (no
/// STEP edge past the hold's bound; RUNNING, held, at rest; MOTION's last stop DOOR);
/// RESUME and RUNING are refused `DOOR_OPEN` while it is open; closed, a RESUME lets the
/// run end with every point executed and the joint exactly on its last point.
#[test]
fn an_open_door_holds_the_run_refuses_resume_and_closed_the_run_ends_exact() {
    if let Some(reason) = unavailable() {
        note(&reason);
        return;
    }
    let mut board = RenodeBoard::start_door_with_step_path(WATCH_DOOR);
    let arm = Arc::new(board.connect_from(HOSTS[0], emulated()));
    let status = arm.status().unwrap();
    assert_eq!(status.state, State::Stopped, "{status:?}\n{}", board.log());
    assert_eq!(
        motion_flags(&arm) & MotionFlags::DOOR_OPEN,
        0,
        "closed at boot"
    );
    let start = arm
        .current_location(Duration::from_secs(5))
        .unwrap()
        .position;

    // 200 points of 10 ms, joint 0 +4 steps each (400 steps/s, a 2.5 ms period).
    let runner = run_reporting_progress_with(&arm, points(start, 200, 4), held_run_options());
    runner.wait_executed(20);
    board.monitor("sysbus.gpioPortF OnGPIO 4 true");
    wait_motion(
        &board,
        &arm,
        MotionFlags::HELD | MotionFlags::AT_REST | MotionFlags::DOOR_OPEN,
        "held at rest by the door",
    );
    let (status, motion) = arm.motion().unwrap();
    let motion = motion.expect("a MOTION report");
    assert_eq!(
        status.state,
        State::Running,
        "held, still RUNNING: {status:?}"
    );
    assert!(
        status.executed < 200,
        "the run was held part way: {status:?}"
    );
    assert_eq!(motion.last_stop, Some(ControlledStop::Door), "{motion:?}");

    let edges = board.edges();
    let (opened, last_step) = opened_and_last_step(&board, &edges, DOOR, "PF4");
    let before = edges.iter().filter(|e| e.line < 8 && e.ns < opened).count();
    let after = edges
        .iter()
        .filter(|e| e.line < 8 && e.high && e.ns >= opened)
        .count();
    note(&format!(
        "PF4 high at {opened} ns; last STEP edge at {last_step} ns ({} ns after; bound \
         {HOLD_BOUND_NS} ns); {before} STEP edges before it, {after} rises after; {} points \
         executed",
        i128::from(last_step) - i128::from(opened),
        status.executed
    ));
    assert!(before > 0, "the joint moved before the door opened");
    assert!(
        last_step <= opened + HOLD_BOUND_NS,
        "a STEP edge {} ns after the door opened",
        last_step - opened
    );

    // While open: RESUME and RUNING refused DOOR_OPEN, the run stays held.
    for _ in 0..3 {
        match arm.resume() {
            Err(armctl::Error::Refused { status, .. }) => {
                assert_eq!(status, StatusCode::DoorOpen);
            }
            other => panic!("RESUME with the door open: {other:?}"),
        }
        let ack = arm.exchange(&Command::Runing).unwrap();
        assert_eq!(ack.status, StatusCode::DoorOpen);
    }
    let step_edges =
        |edges: &[system_tests::renode::Edge]| edges.iter().filter(|e| e.line < 8).count();
    assert_eq!(
        step_edges(&board.edges()),
        step_edges(&edges),
        "no STEP edge while held"
    );

    // Closed: the door reads closed; RESUME and the run ends, exact.
    board.monitor("sysbus.gpioPortF OnGPIO 4 false");
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    while motion_flags(&arm) & MotionFlags::DOOR_OPEN != 0 {
        assert!(
            std::time::Instant::now() < deadline,
            "the door never read closed\n{}",
            board.log()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
    arm.resume()
        .unwrap_or_else(|e| panic!("RESUME after closing: {e}\n{}", board.log()));
    let report = runner
        .join()
        .unwrap_or_else(|e| panic!("the held run: {e}\n{}", board.log()));
    note(&format!("the run after closing: {report:?}"));
    let end = arm
        .current_location(Duration::from_secs(5))
        .unwrap()
        .position;
    assert_eq!(end[0], start[0] + 800, "every point ran, exactly");
    board.assert_healthy();
}

/// The recorder's input for the wired e-stop pin (PC0).
const ESTOP: u8 = 43;

/// ESTOP_CATEGORY 1 on the board itself: its step side has no warp, so EXTI0 stops every
/// STEP output as category 0 (no edge later than one step period after PC0 went high),
/// then the controller disables the drivers (category 1's end) and latches; MOTION shows
/// the category. (The same ELF: the e-stop input is in every build.)
#[test]
fn estop_category_1_on_the_board_stops_at_once_then_disables_the_drivers() {
    if let Some(reason) = unavailable() {
        note(&reason);
        return;
    }
    let mut board = RenodeBoard::start_door_with_step_path(
        "sysbus.stepRecorder Watch \"sysbus.gpioPortC\" 0 43",
    );
    let arm = Arc::new(board.connect_from(HOSTS[0], emulated()));
    arm.set_estop_category(protocol::EStopCategory::Controlled)
        .unwrap_or_else(|e| panic!("ESTOP_CATEGORY 1: {e}\n{}", board.log()));
    let (_, motion) = arm.motion().unwrap();
    assert_eq!(
        motion.and_then(|m| m.estop_category),
        Some(protocol::EStopCategory::Controlled)
    );
    let status = arm.status().unwrap();
    assert!(
        status.flags.has(protocol::StatusFlags::DRIVERS_ENABLED),
        "{status:?}"
    );
    let start = arm
        .current_location(Duration::from_secs(5))
        .unwrap()
        .position;
    let period_ns = 2_500_000;
    let runner =
        run_reporting_progress_with(&arm, points(start, 200, 4), armctl::RunOptions::default());
    runner.wait_executed(20);
    board.monitor("sysbus.gpioPortC OnGPIO 0 true");
    let end = runner.join();
    note(&format!("the run: {end:?}"));
    let status = arm
        .wait_stopped(Duration::from_secs(60))
        .unwrap_or_else(|e| panic!("STOPPED after the e-stop: {e}\n{}", board.log()));
    let edges = board.edges();
    let (opened, last_step) = opened_and_last_step(&board, &edges, ESTOP, "PC0");
    note(&format!(
        "category 1 on the board: PC0 high at {opened} ns, last STEP edge {} ns after \
         (step period {period_ns} ns); {} points executed",
        i128::from(last_step) - i128::from(opened),
        status.executed
    ));
    assert!(
        last_step <= opened + period_ns,
        "a STEP edge {} ns after PC0 went high",
        last_step - opened
    );
    // The drivers go off once the task applied it (bounded wait on what STATUS shows).
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    let status = loop {
        let status = arm.status().unwrap();
        if !status.flags.has(protocol::StatusFlags::DRIVERS_ENABLED) {
            break status;
        }
        assert!(
            std::time::Instant::now() < deadline,
            "the drivers stayed enabled: {status:?}\n{}",
            board.log()
        );
        std::thread::sleep(Duration::from_millis(50));
    };
    assert_eq!(status.state, State::Stopped);
    assert!(
        status
            .more_flags
            .has(protocol::MoreFlags::ESTOP_LATCHED | protocol::MoreFlags::ESTOP_OPEN),
        "{status:?}"
    );
    let (_, stop) = arm.stop_report().unwrap();
    assert_eq!(stop.and_then(|s| s.cause), Some(StopCause::EstopInput));
    let ack = arm.exchange(&Command::Runing).unwrap();
    assert_eq!(ack.status, StatusCode::EstopLatched);
    board.monitor("sysbus.gpioPortC OnGPIO 0 false");
    board.assert_healthy();
}
