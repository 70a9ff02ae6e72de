//! Issue 32's "an underrun at speed with enough buffered path decelerates within the
//! acceleration (trace)", in the simulator on virtual time (`VirtualBoard`: every figure
//! is simulated time). Joint 0 cruises at 4,000 steps/s with ACCEL_SET 20,000 steps/s^2;
//! the host announces the whole trajectory but sends only its first 2.6 s and goes
//! silent. The controller slows along what it holds (v^2/2a = 400 steps of ramp) to the
//! underrun creep and ends at the last point sent: no two consecutive STEP intervals imply
//! more than 1.1 x the limit, the joint is exactly on the last point sent, STOPPED with
//! cause UNDERRUN and STOP_CAUSE detail 1, MOTION's last stop UNDERRUN. Without ACCEL_SET
//! the same host gets the dead underrun (detail 0) as before. Figures printed
//! (`--nocapture`).

mod virtual_host;

use armctl::vcd;
use protocol::{
    Command, ControlledStop, MAX_JOINTS, MotionReport, Point, PointList, State, StopCause,
    StopReport,
};
use virtual_host::*;

/// 200 MHz step timer: tick rounding (5 ns) does not show in the implied accelerations.
const TICK_HZ: u32 = 200_000_000;
/// Joint 0's cruise, steps per 10 ms point: 4,000 steps/s.
const CRUISE: i32 = 40;
/// ACCEL_SET for joint 0, steps/s^2.
const ACCEL: u32 = 20_000;
/// Points the host sends before going silent: the ramp up (40) and 2.2 s of cruise.
const SENT: usize = 260;

/// Joint 0 from rest up to `CRUISE` (+1 a point: 10,000 steps/s^2), 400 points at it,
/// and down to rest.
fn trajectory() -> Vec<Point> {
    let steps = (1..=CRUISE)
        .chain(std::iter::repeat_n(CRUISE, 400))
        .chain((1..CRUISE).rev());
    let mut at = [0; MAX_JOINTS];
    steps
        .map(|s| {
            let before = at;
            at[0] += s;
            Point::from_motion(10_000, &before, &at)
        })
        .collect()
}

/// Runs the late host; returns the rises of joint 0, the last point sent, and the reports.
fn late_host(name: &str, accel: Option<u32>) -> (Vec<u64>, i64, StopReport, MotionReport) {
    let (mut board, trace) = board(name, TICK_HZ);
    let mut host = Host::new();
    if let Some(max) = accel {
        host.ok(
            &mut board,
            &Command::AccelSet {
                joint: 0,
                max_accel_steps_s2: max,
            },
        );
    }
    let points = trajectory();
    host.ok(
        &mut board,
        &Command::New {
            count: points.len() as u16,
        },
    );
    for chunk in points[..SENT].chunks(protocol::MAX_POINTS_PER_FRAME) {
        host.ok(&mut board, &Command::Pending(PointList::Points(chunk)));
    }
    host.ok(&mut board, &Command::Runing);
    let last = run_until_stopped(&mut board, 60 * SECOND_NS);
    assert_eq!(
        last.position,
        points[SENT - 1].position,
        "on the last point sent"
    );
    let status = host.status(&mut board);
    assert_eq!(status.state, State::Stopped);
    assert_eq!(status.stop_cause(), Some(StopCause::Underrun));
    assert_eq!(
        usize::from(status.executed),
        SENT,
        "every point sent executed"
    );
    let (stop, motion) = stop_and_motion(&mut host, &mut board);
    board.finish_trace();
    let vcd = vcd::read_changes(&trace).unwrap();
    let end = i64::from(points[SENT - 1].position[0]);
    assert_eq!(vcd.joint_position(0), end);
    (vcd.rising_edges("step0"), end, stop, motion)
}

/// Steps/s^2 each two consecutive intervals imply (rises in ns).
fn implied(rises: &[u64]) -> Vec<f64> {
    rises
        .windows(3)
        .map(|w| {
            let i1 = (w[1] - w[0]) as f64 * 1e-9;
            let i2 = (w[2] - w[1]) as f64 * 1e-9;
            (1.0 / i2 - 1.0 / i1).abs() / ((i1 + i2) / 2.0)
        })
        .collect()
}

#[test]
fn an_underrun_at_speed_with_enough_path_decelerates_within_the_acceleration() {
    let (rises, end, stop, motion) = late_host("underrun_controlled", Some(ACCEL));
    assert_eq!(rises.len() as i64, end, "one rise a step");
    // The ramp: from the first interval longer than the cruise's to the last rise.
    let start = rises
        .windows(2)
        .position(|w| w[1] - w[0] > 250_000 + 100 && w[0] > rises[0] + 500_000_000)
        .expect("a slow-down");
    // From 0.1 s of cruise before it (the trajectory's own ramp up is made of constant-
    // speed points whose joins imply more: the file's business, not the underrun's).
    let from = start.saturating_sub(400);
    let max = implied(&rises[from..]).into_iter().fold(0.0, f64::max);
    let crawl = rises
        .windows(2)
        .filter(|w| w[1] - w[0] >= 4_900_000)
        .count();
    let ramp_steps = rises.len() - 1 - start - crawl;
    let ramp_s = (rises[rises.len() - 1] - rises[start]) as f64 * 1e-9;
    let last_interval = (rises[rises.len() - 1] - rises[rises.len() - 2]) as f64 * 1e-9;
    println!(
        "controlled underrun: {} steps; {ramp_steps} in the ramp (v^2/2a = 400 to rest), \
         then {crawl} at the creep, {ramp_s:.4} s from the slow-down to the last step (v/a = \
         0.2 s to rest, plus the crawl); max implied acceleration from 0.1 s before it \
         {max:.0} steps/s^2 = {:.4} x the limit; last interval {:.2} ms ({:.0} steps/s); \
         STOP_CAUSE detail {}, MOTION last stop {:?}",
        rises.len(),
        max / f64::from(ACCEL),
        last_interval * 1e3,
        1.0 / last_interval,
        stop.detail,
        motion.last_stop,
    );
    assert!(max <= 1.1 * f64::from(ACCEL), "{max} steps/s^2");
    assert!(
        (380..=420).contains(&ramp_steps),
        "{ramp_steps} steps of ramp"
    );
    assert_eq!((stop.cause, stop.detail), (Some(StopCause::Underrun), 1));
    assert_eq!(motion.last_stop, Some(ControlledStop::Underrun));
}

#[test]
fn without_accel_set_the_underrun_stays_dead() {
    let (rises, _, stop, motion) = late_host("underrun_dead", None);
    let last_interval = (rises[rises.len() - 1] - rises[rises.len() - 2]) as f64 * 1e-9;
    println!(
        "dead underrun: last interval {:.3} ms ({:.0} steps/s, the cruise), detail {}",
        last_interval * 1e3,
        1.0 / last_interval,
        stop.detail
    );
    assert_eq!((stop.cause, stop.detail), (Some(StopCause::Underrun), 0));
    assert_eq!(motion.last_stop, Some(ControlledStop::None));
    assert!(last_interval < 0.000_26, "at cruise speed to the end");
}

/// The safety door (issue 32) in the simulator: opening it 1 s into a run holds the run
/// within the acceleration, no STEP edge while it is open; RESUME is refused
/// DOOR_OPEN until it closes; closing it and a RESUME finish the run exactly.
#[test]
fn the_safety_door_holds_the_run_and_closing_it_and_a_resume_go_on() {
    let (mut board, trace) = board("door", TICK_HZ);
    let mut host = Host::new();
    host.ok(
        &mut board,
        &Command::AccelSet {
            joint: 0,
            max_accel_steps_s2: ACCEL,
        },
    );
    let points = trajectory();
    let end = points.last().unwrap().position;
    host.upload_and_run(&mut board, &points);
    board.run_for(SECOND_NS);
    let open_ns = board.clock.now_ns();
    board.set_door(true);
    board.run_for(SECOND_NS);
    let at_rest = board.motors.positions()[0];
    let ack = host.command(&mut board, &Command::Resume);
    assert_eq!(ack.status, protocol::StatusCode::DoorOpen);
    let (_, motion) = stop_and_motion(&mut host, &mut board);
    assert!(
        motion
            .flags
            .has(protocol::MotionFlags::DOOR_OPEN | protocol::MotionFlags::HELD)
    );
    assert_eq!(motion.last_stop, Some(ControlledStop::Door));
    board.run_for(SECOND_NS / 2);
    assert_eq!(board.motors.positions()[0], at_rest, "no step while open");
    board.set_door(false);
    board.run_for(SECOND_NS / 10);
    assert_eq!(
        board.motors.positions()[0],
        at_rest,
        "closing alone: still held"
    );
    let resume_ns = board.clock.now_ns();
    host.ok(&mut board, &Command::Resume);
    let last = run_until_stopped(&mut board, 60 * SECOND_NS);
    assert_eq!(last.position, end, "on the last point");
    let status = host.status(&mut board);
    assert_eq!(usize::from(status.executed), points.len());
    board.finish_trace();
    let vcd = vcd::read_changes(&trace).unwrap();
    assert_eq!(vcd.joint_position(0), i64::from(end[0]));
    let rises = vcd.rising_edges("step0");
    let window: Vec<u64> = rises
        .iter()
        .copied()
        .filter(|t| (open_ns - SECOND_NS / 10..resume_ns).contains(t))
        .collect();
    let max = implied(&window).into_iter().fold(0.0, f64::max);
    let last_held = window.last().copied().unwrap_or(open_ns);
    println!(
        "door opened 1 s into the run: last step {:.4} s after it, max implied acceleration \
         {:.4} x the limit; RESUME while open: DOOR_OPEN; closed and resumed: every point \
         ran, joint on its last point",
        (last_held - open_ns) as f64 * 1e-9,
        max / f64::from(ACCEL)
    );
    assert!(max <= 1.1 * f64::from(ACCEL), "{max}");
    assert!(
        last_held - open_ns <= 320_000_000,
        "to rest within v/a + lookahead + 20 ms"
    );
}
