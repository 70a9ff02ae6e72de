//! Issue 31: the controller keeps each joint's most acceleration (ACCEL_SET, with the
//! limits) and refuses a point that implies more (INVALID_POINT, LIMITS reason 8, naming
//! joint and point). Before, acceleration lived only in armctl's config and an instant
//! reversal passed on the controller. docs/PROTOCOL.md, ACCEL_SET, has the definition and
//! this worked example.

mod common;

use arm_core::Deferred;
use common::*;
use protocol::{Command, MAX_JOINTS, Point, PointList, RefusalReason, State, StatusCode, Tag};

/// 10 ms points moving joint 0 by each of `steps`, from `from`.
fn moves(from: i32, steps: &[i32]) -> Vec<Point> {
    let mut at = [0; MAX_JOINTS];
    at[0] = from;
    steps
        .iter()
        .map(|s| {
            let before = at;
            at[0] += s;
            Point::from_motion(10_000, &before, &at)
        })
        .collect()
}

fn accel_set(s: &mut Session<64>, joint: u8, max: u32) -> protocol::Ack {
    s.send(Command::AccelSet {
        joint,
        max_accel_steps_s2: max,
    })
}

fn limits_with_accel(s: &mut Session<64>) -> protocol::LimitsReport {
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(HOST, &frame(s.seq, Command::LimitsGetWithAccel));
    r.limits.expect("a LIMITS report").1
}

#[test]
fn the_worked_example_is_refused_at_its_third_point_naming_joint_and_point() {
    let mut s = Session::<64>::new(64);
    assert_eq!(accel_set(&mut s, 0, 100_000).status, StatusCode::Ok);
    s.expect(Command::New { count: 10 }, StatusCode::Ok);
    // +5 from rest (80,000 steps/s²): taken.
    assert_eq!(s.pending(&moves(0, &[5])).status, StatusCode::Ok);
    // +15 (80,000), then +30 after it (130,000 steps/s², over 100,000): the whole frame
    // refused, its point 1 named.
    let ack = s.pending(&moves(5, &[15, 30]));
    assert_eq!(ack.status, StatusCode::InvalidPoint);
    assert_eq!(s.controller.buffered(), 1, "nothing of the frame taken");
    let seq = s.seq;
    let report = limits_with_accel(&mut s);
    let r = report.last_refusal;
    assert_eq!(
        (r.seq, r.tag, r.point, r.joint, r.reason, r.value, r.limit),
        (
            seq,
            Tag::Pending as u8,
            1,
            0,
            RefusalReason::Acceleration,
            130_000,
            100_000
        )
    );
    assert_eq!(report.max_accel.map(|a| a[0]), Some(100_000));
    // Within the limit (+15, +25: 80,000 each) it is taken, with the refused frame's seq
    // (its seq is still the upload's next, section 7).
    s.seq = seq.wrapping_sub(1);
    assert_eq!(s.pending(&moves(5, &[15, 25])).status, StatusCode::Ok);
}

#[test]
fn an_instant_reversal_is_refused_with_a_limit_and_taken_without() {
    for (max, want) in [(0, StatusCode::Ok), (1_000_000, StatusCode::InvalidPoint)] {
        let mut s = Session::<64>::new(64);
        accel_set(&mut s, 0, max);
        s.expect(Command::New { count: 10 }, StatusCode::Ok);
        // Ramp up gently, then +100 and -100 (10,000 steps/s each way, 1,980,000 steps/s²
        // between them).
        assert_eq!(
            s.pending(&moves(0, &[1, 2, 50, 100])).status,
            StatusCode::Ok,
            "{max}"
        );
        assert_eq!(s.pending(&moves(153, &[-100])).status, want, "max {max}");
    }
}

#[test]
fn the_last_point_must_come_to_rest() {
    let mut s = Session::<64>::new(64);
    accel_set(&mut s, 0, 100_000);
    // Two points ending at 15 steps per 10 ms: stopping from there is 280,000 steps/s².
    s.expect(Command::New { count: 2 }, StatusCode::Ok);
    assert_eq!(
        s.pending(&moves(0, &[5, 15])).status,
        StatusCode::InvalidPoint
    );
    s.expect(Command::New { count: 3 }, StatusCode::Ok);
    assert_eq!(s.pending(&moves(0, &[5, 7, 3])).status, StatusCode::Ok);
    s.expect(Command::Runing, StatusCode::Ok);
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.controller.state(), State::Stopped);
    assert_eq!(s.plant.positions[0], 15);
}

#[test]
fn other_joints_and_joints_without_a_limit_are_not_checked() {
    let mut s = Session::<64>::new(64);
    accel_set(&mut s, 1, 10);
    s.expect(Command::New { count: 2 }, StatusCode::Ok);
    let mut a = [0; MAX_JOINTS];
    a[0] = 500;
    let mut b = a;
    b[0] = 0;
    let pts = [
        Point::from_motion(10_000, &[0; MAX_JOINTS], &a),
        Point::from_motion(10_000, &a, &b),
    ];
    assert_eq!(
        s.send(Command::Pending(PointList::Points(&pts))).status,
        StatusCode::Ok
    );
}

#[test]
fn accel_set_is_kept_with_the_limits_only_while_stopped() {
    let mut s = Session::<64>::new(64);
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(
        HOST,
        &frame(
            s.seq,
            Command::AccelSet {
                joint: 3,
                max_accel_steps_s2: 40_000,
            },
        ),
    );
    assert_eq!(r.reply.map(|r| r.ack.status), Some(StatusCode::Ok));
    let Some(Deferred::SaveSettings(saved)) = r.deferred else {
        panic!("saved: {:?}", r.deferred)
    };
    assert_eq!(saved.max_accel[3], 40_000);
    // Applied at the next boot.
    let mut booted = Session::<64>::new(64);
    booted.controller.apply_settings(saved);
    assert_eq!(
        limits_with_accel(&mut booted).max_accel.map(|a| a[3]),
        Some(40_000)
    );
    // Not during an upload; a joint of 8: INVALID_CONFIG (decoded).
    s.expect(Command::New { count: 2 }, StatusCode::Ok);
    assert_eq!(accel_set(&mut s, 3, 1).status, StatusCode::BadState);
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(
        HOST,
        &raw(s.seq, Tag::AccelSet as u8, &[8, 0, 0, 0, 1, 0, 0, 0]),
    );
    assert_eq!(
        r.reply.map(|r| r.ack.status),
        Some(StatusCode::InvalidConfig)
    );
    // The plain LIMITS_GET of old hosts: the 112-byte report, no accelerations.
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(HOST, &frame(s.seq, Command::LimitsGet));
    assert_eq!(r.limits.expect("LIMITS").1.max_accel, None);
}
