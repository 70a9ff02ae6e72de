//! Issue 31, "a limp joint moves": after `armctl disable 1`, `move 1=500` was accepted,
//! STATUS showed joint 1 at 500, and all 500 pulses went to a disabled driver. The
//! controller now refuses motion of a joint whose driver is disabled with INVALID_POINT,
//! and the LIMITS report's last refusal names the joint (reason 7), whatever the host.

mod common;

use common::*;
use protocol::{Command, MAX_JOINTS, Point, RefusalReason, State, StatusCode, Tag};

fn disable(s: &mut Session<64>, mask: u16) {
    s.expect(
        Command::SetEnable {
            mask,
            enable: false,
        },
        StatusCode::Ok,
    );
}

fn last_refusal(s: &mut Session<64>) -> protocol::Refusal {
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(HOST, &frame(s.seq, Command::LimitsGet));
    r.limits.expect("a LIMITS report").1.last_refusal
}

#[test]
fn a_point_moving_a_disabled_joint_is_refused_and_names_it() {
    let mut s = Session::<64>::new(64);
    disable(&mut s, 1 << 1);
    s.expect(Command::New { count: 1 }, StatusCode::Ok);
    let mut target = [0; MAX_JOINTS];
    target[1] = 500;
    let ack = s.pending(&[Point::from_motion(1_000_000, &[0; MAX_JOINTS], &target)]);
    assert_eq!(ack.status, StatusCode::InvalidPoint, "joint 1 is limp");
    assert_eq!(s.controller.buffered(), 0, "nothing taken");
    let pending_seq = s.seq;
    let refusal = last_refusal(&mut s);
    assert_eq!(refusal.reason, RefusalReason::JointDisabled);
    assert_eq!(
        (
            refusal.seq,
            refusal.tag,
            refusal.joint,
            refusal.value,
            refusal.limit
        ),
        (pending_seq, Tag::Pending as u8, 1, 500, 0)
    );
    // Nothing moved and STATUS does not show joint 1 at 500.
    assert_eq!(s.plant.positions[1], 0);
    assert!(s.plant.executed.is_empty());
}

#[test]
fn other_joints_still_move_while_one_is_limp() {
    let mut s = Session::<64>::new(64);
    disable(&mut s, 1 << 1);
    let mut target = [0; MAX_JOINTS];
    target[0] = 200;
    target[2] = -100;
    s.start_run(1, &[Point::from_motion(100_000, &[0; MAX_JOINTS], &target)]);
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.controller.state(), State::Stopped);
    assert_eq!(s.plant.positions[..3], [200, 0, -100]);
}

#[test]
fn enabled_again_it_moves() {
    let mut s = Session::<64>::new(64);
    disable(&mut s, 1 << 1);
    s.expect(
        Command::SetEnable {
            mask: 1 << 1,
            enable: true,
        },
        StatusCode::Ok,
    );
    let mut target = [0; MAX_JOINTS];
    target[1] = 500;
    s.start_run(
        1,
        &[Point::from_motion(1_000_000, &[0; MAX_JOINTS], &target)],
    );
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.plant.positions[1], 500);
}

#[test]
fn return_is_refused_while_a_limp_joint_is_away_from_zero() {
    let mut s = Session::<64>::new(64);
    s.set_location([0, 300, 0, 0, 0, 0, 0, 0]);
    disable(&mut s, 1 << 1);
    s.expect(Command::Return, StatusCode::InvalidPoint);
    assert_eq!(s.controller.state(), State::Stopped, "nothing moves");
    let refusal = last_refusal(&mut s);
    assert_eq!(
        (refusal.tag, refusal.joint, refusal.reason),
        (Tag::Return as u8, 1, RefusalReason::JointDisabled)
    );
    // A limp joint already at 0 does not stop RETURN of the others.
    s.set_location([40, 0, 0, 0, 0, 0, 0, 0]);
    s.expect(Command::Return, StatusCode::Ok);
}
