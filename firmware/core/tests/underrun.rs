//! Issue 32: a controlled underrun. While the host still owes points and a joint has an
//! ACCEL_SET limit, the controller slows the run along what it holds when the path left is
//! about what the ramp needs, so the run ends at its last point at a crawl (STOPPED,
//! UNDERRUN, STOP_CAUSE detail 1, MOTION's last stop UNDERRUN); points arriving in time
//! ramp it back. Without a limit, the underrun is the dead stop it always was (detail 0).

mod common;

use common::*;
use protocol::{
    Command, ControlledStop, MAX_JOINTS, MotionFlags, Point, State, StatusCode, StopCause,
};

const ONE: u64 = arm_step::RATE_ONE;
/// Joint 0's limit: 4,000 steps/s comes to the creep in 0.1 s, about 50 ms of path.
const ACCEL: u32 = 40_000;

/// 10 ms points of joint 0: a ramp of +2, +4, .. +40 steps from rest (16,000 steps/s^2
/// between points), then `cruise` points of +40 (4,000 steps/s).
fn path(cruise: usize) -> Vec<Point> {
    let mut at = [0i32; MAX_JOINTS];
    let steps = (1..=20)
        .map(|k| 2 * k)
        .chain(std::iter::repeat_n(40, cruise));
    steps
        .map(|d| {
            let before = at;
            at[0] += d;
            Point::from_motion(10_000, &before, &at)
        })
        .collect()
}

/// NEW of `count`, the first `sent` points of `pts` (PENDING by tens), RUNING.
fn start(s: &mut Session<64>, count: u16, pts: &[Point], sent: usize) {
    s.expect(Command::New { count }, StatusCode::Ok);
    for chunk in pts[..sent].chunks(10) {
        assert_eq!(s.pending(chunk).status, StatusCode::Ok);
    }
    s.expect(Command::Runing, StatusCode::Ok);
}

/// Runs segment by segment until the first rate change (or the run's end); returns how
/// many segments ran.
fn run_until_rate_change(s: &mut Session<64>) -> usize {
    let mut n = 0;
    while s.plant.running && s.plant.rate_changes.is_empty() {
        s.plant.run(&mut s.controller, 1);
        n += 1;
    }
    n
}

#[test]
fn a_late_host_with_enough_path_held_gets_a_ramp_and_a_controlled_underrun() {
    let mut s = Session::<64>::new(64);
    s.expect(
        Command::AccelSet {
            joint: 0,
            max_accel_steps_s2: ACCEL,
        },
        StatusCode::Ok,
    );
    let pts = path(30);
    start(&mut s, 200, &pts, 50);
    let ran = run_until_rate_change(&mut s);
    let creep = ONE * 5 / 100;
    assert_eq!(s.plant.rate_changes, vec![(creep, ACCEL, 4_000)]);
    // The ramp needs (1 - 0.05^2) * 4,000 / (2 * 40,000) s = 49.9 ms of path: it starts
    // with five or six 10 ms points held after the one running.
    let held = 50 - ran;
    assert!((6..=8).contains(&held), "ramp with {held} points held");
    assert!(
        s.controller
            .motion_report(&s.plant)
            .flags
            .has(MotionFlags::UNDERRUN_RAMP)
    );
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.controller.state(), State::Stopped);
    let stop = s.controller.stop_report();
    assert_eq!((stop.cause, stop.detail), (Some(StopCause::Underrun), 1));
    let report = s.controller.motion_report(&s.plant);
    assert_eq!(report.last_stop, Some(ControlledStop::Underrun));
    assert!(!report.flags.has(MotionFlags::UNDERRUN_RAMP));
    // Every point held ran: the arm is where the last one sent says.
    assert_eq!(s.plant.positions, pts[49].position);
    assert_eq!(s.plant.rate_changes.len(), 1);
}

#[test]
fn a_host_that_catches_up_ramps_back_to_the_override() {
    let mut s = Session::<64>::new(64);
    s.expect(
        Command::AccelSet {
            joint: 0,
            max_accel_steps_s2: ACCEL,
        },
        StatusCode::Ok,
    );
    let pts = path(60);
    start(&mut s, 200, &pts, 40);
    run_until_rate_change(&mut s);
    assert_eq!(s.plant.rate_changes.len(), 1, "slowing");
    for chunk in pts[40..].chunks(10) {
        assert_eq!(s.pending(chunk).status, StatusCode::Ok);
    }
    s.plant.run(&mut s.controller, 1);
    assert_eq!(s.plant.rate_changes.last(), Some(&(ONE, ACCEL, 4_000)));
    assert!(
        !s.controller
            .motion_report(&s.plant)
            .flags
            .has(MotionFlags::UNDERRUN_RAMP)
    );
    // Late again: a second ramp, and the run ends at the last point sent.
    s.plant.run_to_end(&mut s.controller);
    let stop = s.controller.stop_report();
    assert_eq!((stop.cause, stop.detail), (Some(StopCause::Underrun), 1));
    assert_eq!(s.plant.positions, pts[79].position);
    assert_eq!(s.plant.rate_changes.len(), 3);
}

#[test]
fn without_an_accel_limit_or_with_every_point_in_nothing_changes() {
    // No ACCEL_SET: the dead underrun of every controller before (detail 0).
    let mut s = Session::<64>::new(64);
    let pts = path(30);
    start(&mut s, 200, &pts, 50);
    s.plant.run_to_end(&mut s.controller);
    assert!(s.plant.rate_changes.is_empty());
    let stop = s.controller.stop_report();
    assert_eq!((stop.cause, stop.detail), (Some(StopCause::Underrun), 0));
    assert_eq!(
        s.controller.motion_report(&s.plant).last_stop,
        Some(ControlledStop::None)
    );
    // With a limit but every point in: the trajectory's own end, no ramp.
    let mut s = Session::<64>::new(64);
    s.expect(
        Command::AccelSet {
            joint: 0,
            max_accel_steps_s2: ACCEL,
        },
        StatusCode::Ok,
    );
    let mut pts = path(20);
    // Down to rest within the limit: -2 per point.
    let mut at = pts[39].position;
    for d in (0..20).rev().map(|k| 2 * k) {
        let before = at;
        at[0] += d;
        pts.push(Point::from_motion(10_000, &before, &at));
    }
    start(&mut s, 60, &pts, 60);
    s.plant.run_to_end(&mut s.controller);
    assert!(s.plant.rate_changes.is_empty());
    assert_eq!(s.controller.stop_report().cause, Some(StopCause::Complete));
}

/// A host that keeps a small buffer full is in time, however short the buffer is for the
/// ramp: no slow-down (the watch acts on a buffer at most half full). Before that rule
/// the watch slowed it to the creep for good: the 16 points held are about the ramp's
/// path, and it could never hold twice that to ramp back.
#[test]
fn a_host_keeping_a_short_buffer_full_is_not_slowed() {
    let mut s = Session::<16>::new(16);
    // 4,000 steps/s to the creep with 14,500 steps/s^2 needs 137.6 ms: 14 of the 16
    // points. The path ramps up by +1 per point (8,000 steps/s^2).
    let accel = 14_500;
    s.expect(
        Command::AccelSet {
            joint: 0,
            max_accel_steps_s2: accel,
        },
        StatusCode::Ok,
    );
    let mut at = [0i32; MAX_JOINTS];
    let pts: Vec<Point> = (1..=40)
        .chain(std::iter::repeat_n(40, 200))
        .map(|d| {
            let before = at;
            at[0] += d;
            Point::from_motion(10_000, &before, &at)
        })
        .collect();
    s.expect(Command::New { count: 400 }, StatusCode::Ok);
    for chunk in pts[..16].chunks(8) {
        assert_eq!(s.pending(chunk).status, StatusCode::Ok);
    }
    s.expect(Command::Runing, StatusCode::Ok);
    let mut sent = 16;
    while sent < pts.len() {
        s.plant.run(&mut s.controller, 1);
        // In time: the point that frees room is replaced at once.
        let room = s.controller.free();
        let next = (sent + room.min(10)).min(pts.len());
        if next > sent {
            assert_eq!(s.pending(&pts[sent..next]).status, StatusCode::Ok);
            sent = next;
        }
    }
    assert!(
        s.plant.rate_changes.is_empty(),
        "{:?}",
        s.plant.rate_changes
    );
    // Then it goes silent: by the time the buffer is half empty the path held is shorter
    // than the ramp: the dead underrun, as before.
    s.plant.run_to_end(&mut s.controller);
    let stop = s.controller.stop_report();
    assert_eq!((stop.cause, stop.detail), (Some(StopCause::Underrun), 0));
    assert_eq!(s.plant.positions, pts[pts.len() - 1].position);
}
