//! A stop never cuts a STEP pulse short, on the NUCLEO-H743ZI2 firmware itself (the `cargo
//! fw` ELF) on Renode with the step path's models and edge recorder
//! (`tests/renode/step-path.resc`, as `renode_steps.rs`).
//!
//! A STEP pulse is counted as made when it rises, so a stop that lands while one is high must
//! let it last the drivers' least high time: a pulse cut shorter may be missed by the driver
//! while the controller counts it, and the arm is a step away from where it says. Eight
//! joints step at 160 kHz (each pulse 2.5 us of a 6.25 us period), so a stop finds one or
//! more of them high most of the time; each test stops runs until one did (at most
//! [`ATTEMPTS`]) and checks, for every pulse on every joint:
//!
//! - it was high for at least the profile's pulse width (the default build's opto drivers:
//!   2,500 ns on the chip, 500 ticks), the ones under way at the stop (risen before their
//!   timer's counter froze, fallen after) included;
//! - the positions the board reports are the pulses its pins made, signed by DIR.
//!
//! Two stops: STOPPED from the network (the stop under the step lock or from the Ethernet
//! interrupt) and the wired e-stop input (PC0, the stop from its own interrupt above the step
//! lock). Both failed before the stop finished a pulse under way (`step_dma/stop.rs`): it
//! forced every output low one store after the counter froze (CI on 01d56cf: "joint 2: STEP
//! edges off the timer's tick grid" in `renode_steps.rs`'s e-stop test).
//!
//! Needs Renode and root, as `renode_steps.rs`; without them each test prints what it needs
//! and passes.

mod common;

use std::sync::Arc;
use std::time::{Duration, Instant};

use arm_core::profile::NUCLEO_H743ZI2;
use armctl::{Error, RunEnd, RunOptions};
use common::{assert_stays_put, run_reporting_progress_with};
use protocol::{Command, MAX_JOINTS, Point, StatusCode};
use system_tests::renode::emulated_eight_joints;
use system_tests::renode::{EMULATED_TIMER_HZ, Edge, HOSTS, RenodeBoard};
use system_tests::require_renode;

/// Prints a figure to the real stderr (seen without --nocapture).
fn note(text: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr().lock(), "renode stop pulse: {text}");
}

/// Runs stopped per test at most. Were the joints' phases independent, a stop would find
/// none of the 8 high about once in 60; they are not quite (in step, 4 STOPPEDs of 4 found
/// none), and measured at these rates STOPPED found none in 1 stop of 8, the e-stop input
/// in none of 4. Taken as one in four, twelve all missing is about one in 17 million.
const ATTEMPTS: usize = 12;

/// Steps per 2 ms point on joint 0 (160 kHz); joint `j` makes `j` * [`STEPS_APART`] more, so
/// that the joints' pulses drift apart in phase (in step, one stop would find all eight
/// high or all low).
const STEPS_PER_POINT: i32 = 320;
/// Joint `j`'s extra steps per point (joint 7: 362, 181 kHz, below the opto drivers' 200).
const STEPS_APART: i32 = 6;

/// The recorder's input for the e-stop pin (PC0).
const ESTOP_LINE: u8 = 43;

/// The emulated CPU at the chip's instruction rate (as `renode_steps.rs`'s eight-joint
/// runs: the refills keep up with 1.28 M steps/s), and the recorder on PC0.
const MONITOR: &str = "sysbus.cpu PerformanceInMips 400; \
    sysbus.stepRecorder Watch \"sysbus.gpioPortC\" 0 43";

/// How a run is stopped.
#[derive(Clone, Copy, Debug)]
enum Stop {
    /// STOPPED from the owner.
    Stopped,
    /// The wired e-stop input opened (PC0 high), then closed and ESTOP_RESET.
    EstopInput,
}

/// A slow first point (its pulses long after the DIR setup), then 100 points of 2 ms at
/// 160-181 kHz on the 8 joints: 200 ms, far longer than the stop takes to come.
fn fast_run(start: [i32; MAX_JOINTS]) -> Vec<Point> {
    let mut at = start;
    let mut points = Vec::new();
    for k in 0..101 {
        let mut next = at;
        for (j, p) in next.iter_mut().enumerate() {
            *p += if k == 0 {
                8
            } else {
                STEPS_PER_POINT + STEPS_APART * j as i32
            };
        }
        points.push(Point::from_motion(2_000, &at, &next));
        at = next;
    }
    points
}

/// One joint's pulses among `edges`: (rise, fall) in ns; a pulse still high at the end has
/// no fall.
fn pulses(edges: &[Edge], joint: u8) -> Vec<(u64, Option<u64>)> {
    let mut out: Vec<(u64, Option<u64>)> = Vec::new();
    for e in edges.iter().filter(|e| e.line == joint) {
        if e.high {
            out.push((e.ns, None));
        } else if let Some(last) = out.last_mut().filter(|p| p.1.is_none()) {
            last.1 = Some(e.ns);
        }
    }
    out
}

/// Joint `joint`'s rises among `edges`, signed by its DIR line (high = positive), DIR's
/// level before them being `dir`.
fn signed_pulses(edges: &[Edge], joint: u8, mut dir: bool) -> i32 {
    let mut made = 0;
    for e in edges {
        if e.line == 8 + joint {
            dir = e.high;
        } else if e.line == joint && e.high {
            made += if dir { 1 } else { -1 };
        }
    }
    made
}

/// DIR of `joint` as the recorder last saw it (low if it never changed).
fn dir_level(edges: &[Edge], joint: u8) -> bool {
    edges
        .iter()
        .rfind(|e| e.line == 8 + joint)
        .is_some_and(|e| e.high)
}

fn position(board: &RenodeBoard, arm: &armctl::Client) -> [i32; MAX_JOINTS] {
    arm.current_location(Duration::from_secs(5))
        .unwrap_or_else(|e| panic!("a LOCATION report: {e}\n{}", board.log()))
        .position
}

/// Stops fast runs with `stop` until a stop found a pulse high, checking every pulse's width
/// and the positions against the pins each time.
fn stops_leave_every_pulse_whole(stop: Stop) {
    let mut board = RenodeBoard::start_with_step_path(MONITOR);
    let arm = Arc::new(board.connect_from(HOSTS[0], emulated_eight_joints()));
    arm.set_joints(8)
        .unwrap_or_else(|e| panic!("SET_JOINTS 8: {e}\n{}", board.log()));
    // The profile's pulse in the emulator's ticks (`EMULATED_TIMER_HZ`: the firmware's
    // 200 MHz ticks run at 250 MHz there, so 2,500 ns on the chip are 2,000 virtual ns).
    let high_ns = u64::from(NUCLEO_H743ZI2.step_timing().pulse_width_ticks) * 1_000_000_000
        / EMULATED_TIMER_HZ;
    let options = RunOptions {
        stall_timeout: Duration::from_secs(120),
        completion_timeout: Some(Duration::from_secs(600)),
        ..RunOptions::default()
    };
    let (mut under_way, mut shortest_under_way) = (0, None::<u64>);
    let mut attempt = 0;
    while attempt < ATTEMPTS && under_way == 0 {
        attempt += 1;
        let before = board.edges();
        let dirs: [bool; MAX_JOINTS] = std::array::from_fn(|j| dir_level(&before, j as u8));
        let start = position(&board, &arm);
        let began = Instant::now();
        let runner = run_reporting_progress_with(&arm, fast_run(start), options.clone());
        runner.wait_executed(5);
        match stop {
            Stop::Stopped => {
                let ack = arm.stop().unwrap();
                assert_eq!(ack.state, protocol::State::Stopped);
            }
            Stop::EstopInput => {
                board.monitor("sysbus.gpioPortC OnGPIO 0 true");
            }
        }
        match runner.join() {
            Err(Error::RunEnded {
                reason: RunEnd::Stopped | RunEnd::EstopInput,
                ..
            }) => {}
            other => panic!(
                "{stop:?}: expected RunEnded(Stopped), got {other:?}\n{}",
                board.log()
            ),
        }
        let reported = assert_stays_put(&arm, 5);
        let edges: Vec<Edge> = board.edges().split_off(before.len());
        let stopped_at = match stop {
            Stop::Stopped => None,
            Stop::EstopInput => edges
                .iter()
                .find(|e| e.line == ESTOP_LINE && e.high)
                .map(|e| e.ns),
        };
        for joint in 0..MAX_JOINTS as u8 {
            let j = usize::from(joint);
            // The stop's freeze of this joint's counter: its counting line falling.
            let freezes: Vec<u64> = edges
                .iter()
                .filter(|e| e.line == 16 + joint && !e.high)
                .map(|e| e.ns)
                .collect();
            let made = pulses(&edges, joint);
            assert!(
                made.len() > 100,
                "joint {j}: {} pulses before the stop",
                made.len()
            );
            for &(rise, fall) in &made {
                let fall = fall.unwrap_or_else(|| {
                    panic!("{stop:?}: joint {j}: STEP still high (rose at {rise} ns)")
                });
                let at_stop = freezes.iter().any(|&f| rise <= f && f <= fall);
                assert!(
                    fall - rise >= high_ns,
                    "{stop:?}: joint {j}: a pulse high for {} ns (rose at {rise} ns){}: the \
                     drivers need {high_ns} ns (virtual)",
                    fall - rise,
                    if at_stop {
                        ", under way at the stop"
                    } else {
                        ""
                    }
                );
                if at_stop {
                    under_way += 1;
                    shortest_under_way =
                        Some(shortest_under_way.map_or(fall - rise, |s| s.min(fall - rise)));
                }
            }
            let pins = signed_pulses(&edges, joint, dirs[j]);
            assert_eq!(
                reported[j] - start[j],
                pins,
                "{stop:?}: joint {j}: the position reported moved {} steps, the pins made {pins}",
                reported[j] - start[j]
            );
        }
        note(&format!(
            "{stop:?}, attempt {attempt}: {} pulses on 8 joints, {under_way} under way at the \
             stop{}; {:.1} s of wall time",
            (0..MAX_JOINTS as u8)
                .map(|j| pulses(&edges, j).len())
                .sum::<usize>(),
            stopped_at.map_or(String::new(), |ns| format!(" (PC0 high at {ns} ns)")),
            began.elapsed().as_secs_f64()
        ));
        if let Stop::EstopInput = stop {
            release_estop(&board, &arm);
        }
    }
    assert!(
        under_way > 0,
        "{stop:?}: none of {ATTEMPTS} stops landed during a pulse: nothing was tested"
    );
    note(&format!(
        "{stop:?}: {under_way} pulses under way at a stop, the shortest high for {} ns \
         (the drivers need {high_ns})",
        shortest_under_way.unwrap_or(0)
    ));
    board.assert_healthy();
}

/// Closes the e-stop input and clears its latch (ESTOP_RESET until the board has seen the
/// input close: bounded).
fn release_estop(board: &RenodeBoard, arm: &armctl::Client) {
    board.monitor("sysbus.gpioPortC OnGPIO 0 false");
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let ack = arm.exchange(&Command::EstopReset).unwrap();
        if ack.status == StatusCode::Ok {
            return;
        }
        assert!(
            Instant::now() < deadline,
            "ESTOP_RESET still refused: {ack:?}\n{}",
            board.log()
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

#[test]
fn stopped_lets_the_pulse_under_way_finish_its_width() {
    require_renode!();
    stops_leave_every_pulse_whole(Stop::Stopped);
}

#[test]
fn the_estop_input_lets_the_pulse_under_way_finish_its_width() {
    require_renode!();
    stops_leave_every_pulse_whole(Stop::EstopInput);
}
