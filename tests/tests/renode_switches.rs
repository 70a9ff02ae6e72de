//! Issue 33's switch inputs on the NUCLEO-H743ZI2 firmware itself (the `cargo fw` ELF) on
//! Renode, with the step path's models and edge recorder (`tests/renode/step-path.resc`, as
//! `renode_steps.rs`). The switch pins are GPIO inputs the test drives from Renode's monitor
//! (`sysbus.gpioPortA OnGPIO 3 true`: the STM32 GPIO model, SYSCFG's EXTI routing, the EXTI
//! and the NVIC are Renode's own); the recorder also watches them, so the instant a switch
//! closed and every STEP edge are on one virtual clock (ns).
//!
//! - A run into joint 0's max limit (PA3): no STEP edge on any joint later than one step
//!   period after the input went high; the controller latched (STOP_CAUSE: the limit, joint
//!   0, max side; RUNING refused `LIMIT_LATCHED`); the positions it reports are the pulses
//!   the pins made; after UNLOCK, points further in are refused and a jog away runs.
//! - HOME on joint 0's home + min switch (PE2): the test is the joint's physical model, its
//!   physical position the start plus the signed STEP pulses the recorder saw, and it drives
//!   PE2 high while that is at or below the switch's position (seek, back-off, slow
//!   approach); the cycle ends homed and the position reported is the physical one minus
//!   the switch's plus the offset, to the step (the switch's position being where the pin
//!   went high on the final approach, as the recorder saw: the model reacts a monitor round
//!   trip late, which moves where the switch closes, never the equality).
//!
//! Needs Renode and root, as `renode_steps.rs`; without them the test prints what it needs
//! and passes.

mod common;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use armctl::Homed;
use common::run_reporting_progress_with;
use protocol::{
    Command, HomingPhase, HomingSettings, MAX_JOINTS, Point, PointList, State, StatusCode,
    StopCause,
};
use system_tests::renode::emulated;
use system_tests::renode::{Edge, HOSTS, RenodeBoard};
use system_tests::require_renode;

/// Prints a figure to the real stderr (seen without --nocapture).
fn note(text: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr().lock(), "renode switches: {text}");
}

/// The recorder's input for joint 0's max limit pin (PA3, docs/BOARD.md's pin map).
const MAX0: u8 = 40;
/// The recorder's input for joint 0's home + min pin (PE2).
const HOME0: u8 = 41;

/// The recorder watches the switch pins too.
const WATCH_SWITCHES: &str = "sysbus.stepRecorder Watch \"sysbus.gpioPortA\" 3 40; \
                              sysbus.stepRecorder Watch \"sysbus.gpioPortE\" 2 41";

/// Points of `duration_us` from `start` through `targets`.
fn points_through(
    start: [i32; MAX_JOINTS],
    targets: &[[i32; MAX_JOINTS]],
    duration_us: i32,
) -> Vec<Point> {
    let mut previous = start;
    targets
        .iter()
        .map(|target| {
            let point = Point::from_motion(duration_us, &previous, target);
            previous = *target;
            point
        })
        .collect()
}

/// NEW and PENDING for `points`; the first PENDING status that is not OK, or OK.
fn upload(arm: &armctl::Client, points: &[Point]) -> StatusCode {
    let ack = arm
        .exchange(&Command::New {
            count: u16::try_from(points.len()).unwrap(),
        })
        .unwrap();
    assert_eq!(ack.status, StatusCode::Ok, "NEW");
    for chunk in points.chunks(12) {
        let ack = arm
            .exchange(&Command::Pending(PointList::Points(chunk)))
            .unwrap();
        if ack.status != StatusCode::Ok {
            return ack.status;
        }
    }
    StatusCode::Ok
}

/// Signed STEP rises of joint `j` among `edges` (DIR high = positive), from `from_ns`.
fn signed_pulses(edges: &[Edge], j: u8, from_ns: u64) -> i32 {
    let mut dir = false;
    let mut made = 0;
    for e in edges {
        if e.line == 8 + j {
            dir = e.high;
        } else if e.line == j && e.high && e.ns >= from_ns {
            made += if dir { 1 } else { -1 };
        }
    }
    made
}

fn position(board: &RenodeBoard, arm: &armctl::Client) -> [i32; MAX_JOINTS] {
    arm.current_location(Duration::from_secs(5))
        .unwrap_or_else(|e| panic!("a LOCATION report: {e}\n{}", board.log()))
        .position
}

#[test]
fn a_max_limit_switch_stops_every_step_within_a_period_and_latches() {
    require_renode!();
    let mut board = RenodeBoard::start_switches_with_step_path(WATCH_SWITCHES);
    let arm = Arc::new(board.connect_from(HOSTS[0], emulated()));
    let status = arm.status().unwrap();
    assert_eq!(status.state, State::Stopped, "{status:?}\n{}", board.log());
    let start = position(&board, &arm);

    // 200 points of 10 ms: joint 0 +4 steps each (400 steps/s, a 2.5 ms period), joint 1
    // -6 (600 steps/s, 1.67 ms): the shortest period is joint 1's.
    let shortest_period_ns = 1_000_000_000 / 600;
    let targets: Vec<[i32; MAX_JOINTS]> = (1..=200)
        .map(|i| {
            let mut t = start;
            t[0] += 4 * i;
            t[1] -= 6 * i;
            t
        })
        .collect();
    let points = points_through(start, &targets, 10_000);
    let runner = run_reporting_progress_with(&arm, points, armctl::RunOptions::default());
    runner.wait_executed(20);
    // Joint 0 reaches its max limit switch.
    board.monitor("sysbus.gpioPortA OnGPIO 3 true");
    let end = runner.join();
    note(&format!("the run: {end:?}"));
    let status = arm
        .wait_stopped(Duration::from_secs(60))
        .unwrap_or_else(|e| panic!("STOPPED after the limit: {e}\n{}", board.log()));
    assert_eq!(status.state, State::Stopped);
    assert!(status.executed < 200, "the run was cut: {status:?}");

    // No STEP edge on any joint later than one step period after the input went high.
    let edges = board.edges();
    let closed = edges
        .iter()
        .find(|e| e.line == MAX0 && e.high)
        .unwrap_or_else(|| panic!("the recorder saw PA3 go high\n{}", board.log()))
        .ns;
    let last_step = edges
        .iter()
        .filter(|e| e.line < 8)
        .map(|e| e.ns)
        .max()
        .expect("STEP edges");
    let before = edges.iter().filter(|e| e.line < 8 && e.ns < closed).count();
    note(&format!(
        "PA3 high at {closed} ns; last STEP edge of any joint at {last_step} ns ({} ns from \
         the closing; shortest step period {shortest_period_ns} ns); {before} STEP edges \
         before it",
        i128::from(last_step) - i128::from(closed)
    ));
    assert!(before > 0, "the joints moved before the switch closed");
    assert!(
        last_step <= closed + shortest_period_ns,
        "a STEP edge {} ns after the limit closed",
        last_step - closed
    );

    // Latched on joint 0's max side.
    let (_, stop) = arm.stop_report().unwrap();
    let stop = stop.expect("a STOP_CAUSE report");
    assert_eq!(stop.cause, Some(StopCause::LimitSwitch), "{stop:?}");
    assert_eq!(stop.detail, 0x80, "joint 0, max side: {stop:?}");

    // The positions reported are the pulses the pins made.
    let here = position(&board, &arm);
    let made: Vec<i32> = (0..2).map(|j| signed_pulses(&edges, j, 0)).collect();
    assert_eq!(
        [here[0] - start[0], here[1] - start[1]],
        [made[0], made[1]],
        "reported {here:?} from {start:?}"
    );

    // RUNING refused LIMIT_LATCHED (points away from the switch are taken: they may run
    // after UNLOCK).
    let away: Vec<[i32; MAX_JOINTS]> = (1..=10)
        .map(|i| {
            let mut t = here;
            t[0] -= 5 * i;
            t
        })
        .collect();
    assert_eq!(
        upload(&arm, &points_through(here, &away, 20_000)),
        StatusCode::Ok
    );
    for _ in 0..3 {
        let ack = arm.exchange(&Command::Runing).unwrap();
        assert_eq!(ack.status, StatusCode::LimitLatched);
    }
    arm.stop().unwrap();

    // Unlocked with the switch still pressed: further in refused, away runs.
    arm.unlock().unwrap();
    let further: Vec<[i32; MAX_JOINTS]> = (1..=5)
        .map(|i| {
            let mut t = here;
            t[0] += i;
            t
        })
        .collect();
    assert_eq!(
        upload(&arm, &points_through(here, &further, 20_000)),
        StatusCode::LimitLatched
    );
    arm.stop().unwrap();
    let report = arm
        .run_trajectory(
            &points_through(here, &away, 20_000),
            &armctl::RunOptions::default(),
            |_| {},
        )
        .unwrap_or_else(|e| panic!("the jog away: {e}\n{}", board.log()));
    note(&format!("jog away after UNLOCK: {report:?}"));
    let after = position(&board, &arm);
    assert_eq!(after[0], here[0] - 50, "jogged away");
    board.monitor("sysbus.gpioPortA OnGPIO 3 false");
    board.assert_healthy();
}

/// Where joint 0 physically is at boot (its count starts at 0), and its home switch: pressed
/// at or below [`HOME_SWITCH`].
const PHYSICAL_START: i32 = 150;
const HOME_SWITCH: i32 = 0;

#[test]
fn home_on_joint_0s_switch_sets_physical_minus_switch_plus_offset() {
    require_renode!();
    let mut board = RenodeBoard::start_switches_with_step_path(WATCH_SWITCHES);
    let arm = board.connect_from(HOSTS[0], emulated());
    let settings = HomingSettings {
        enabled: true,
        towards_max: false,
        // Input A is the home switch and the min limit (docs/BOARD.md).
        switch_is_limit: true,
        order: 0,
        seek_rate_hz: 400,
        approach_rate_hz: 100,
        backoff_steps: 40,
        max_travel_steps: 1_000,
        offset: -20,
    };
    arm.set_homing(0, settings)
        .unwrap_or_else(|e| panic!("HOMING_SET: {e}\n{}", board.log()));

    // The joint's physical model, on a thread of its own until the cycle ends.
    let done = AtomicBool::new(false);
    let (homed, toggles) = std::thread::scope(|s| {
        let model = s.spawn(|| {
            let mut pressed = false;
            let mut toggles = 0;
            let deadline = Instant::now() + Duration::from_secs(300);
            while !done.load(Ordering::SeqCst) && Instant::now() < deadline {
                let physical = PHYSICAL_START + signed_pulses(&board.edges(), 0, 0);
                let want = physical <= HOME_SWITCH;
                if want != pressed {
                    board.monitor(&format!("sysbus.gpioPortE OnGPIO 2 {want}"));
                    pressed = want;
                    toggles += 1;
                }
            }
            toggles
        });
        let homed = arm.home(Duration::from_secs(240));
        done.store(true, Ordering::SeqCst);
        (homed, model.join().unwrap())
    });
    let report = match homed {
        Ok(Homed::OnSwitches(report)) => report,
        other => panic!("HOME: {other:?}\n{}", board.log()),
    };
    assert_eq!(report.phase, HomingPhase::Homed);
    assert_eq!(report.homed & 1, 1, "{report:?}");

    let edges = board.edges();
    let closings: Vec<u64> = edges
        .iter()
        .filter(|e| e.line == HOME0 && e.high)
        .map(|e| e.ns)
        .collect();
    let last_closing = *closings.last().expect("PE2 went high");
    let physical = PHYSICAL_START + signed_pulses(&edges, 0, 0);
    let switch_at = physical - signed_pulses(&edges, 0, last_closing);
    let reported = position(&board, &arm)[0];
    note(&format!(
        "homed: PE2 driven {toggles} times, closed {} times; the switch closed on the final \
         approach at physical {switch_at} (modelled at {HOME_SWITCH}, the model a monitor \
         round trip late); physical now {physical}, reported {reported}, offset {}",
        closings.len(),
        settings.offset
    ));
    assert!(closings.len() >= 2, "seek and approach each closed it");
    assert_eq!(
        reported,
        physical - switch_at + settings.offset,
        "position = physical - switch + offset"
    );
    board.assert_healthy();
}
