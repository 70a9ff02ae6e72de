//! Issue 33, hard limits in the sans-io controller (`Controller::limit_switch`, UNLOCK,
//! `LIMIT_LATCHED`): a limit switch tripping stops a run as STOPPED does and latches;
//! RUNING and RETURN are refused until UNLOCK; after it, points moving the joint further
//! into the switch are refused while it is active, points moving away are run; once it
//! has opened, anything goes. Without switches nothing changes (UNLOCK is a no-op `OK`).

mod common;

use arm_core::switches::{Side, SwitchEvent};
use common::*;
use protocol::{Command, MAX_JOINTS, State, StatusCode, StopCause};

fn trip(joint: u8, side: Side) -> SwitchEvent {
    SwitchEvent::LimitTripped {
        joint,
        side,
        at_us: 0,
    }
}

#[test]
fn a_limit_trip_stops_the_run_and_latches_until_unlock() {
    let mut s = Session::<64>::new(64);
    s.start_endless_run();
    let stops = s.plant.stops;
    let location = s.controller.limit_switch(trip(0, Side::Max), &mut s.plant);
    assert!(s.plant.stops > stops, "the engine was stopped");
    assert!(!s.plant.running);
    assert_eq!(s.controller.state(), State::Stopped);
    assert_eq!(s.controller.buffered(), 0, "the trajectory is dropped");
    assert_eq!(location.expect("a LOCATION").state, State::Stopped as u8);
    assert_eq!(s.controller.hard_limits().latched(), Some((0, Side::Max)));
    // The stop cause names the switch: LIMIT_SWITCH, joint 0, its max side (bit 7).
    let cause = s.controller.stop_report();
    assert_eq!(cause.cause, Some(StopCause::LimitSwitch), "{cause:?}");
    assert_eq!(cause.detail, 0x80, "{cause:?}");
    // Latched: an upload is taken (away from the switch), but nothing runs.
    s.expect(Command::New { count: 12 }, StatusCode::Ok);
    s.pending(&points(s.plant.positions, 12, -1));
    for attempt in 0..3 {
        let ack = s.expect(Command::Runing, StatusCode::LimitLatched);
        assert_eq!(ack.state, State::Pending, "attempt {attempt}");
        assert!(!s.plant.running);
    }
    // The latch is named before the state (PENDING would be BAD_STATE for RETURN).
    s.expect(Command::Return, StatusCode::LimitLatched);
    s.expect(Command::Stopped, StatusCode::Ok);
    s.expect(Command::Return, StatusCode::LimitLatched);
    // A second trip while latched keeps the first one's name.
    s.controller.limit_switch(trip(3, Side::Min), &mut s.plant);
    assert_eq!(s.controller.hard_limits().latched(), Some((0, Side::Max)));
}

#[test]
fn after_unlock_only_motion_away_from_the_switch_until_it_opens() {
    let mut s = Session::<64>::new(64);
    s.start_endless_run();
    s.controller.limit_switch(trip(0, Side::Max), &mut s.plant);
    s.expect(Command::Unlock, StatusCode::Ok);
    assert_eq!(s.controller.hard_limits().latched(), None);
    // Further in (every joint +1, joint 0 into its max switch): refused.
    s.expect(Command::New { count: 12 }, StatusCode::Ok);
    let ack = s.pending(&points(s.plant.positions, 12, 1));
    assert_eq!(ack.status, StatusCode::LimitLatched);
    // Away (every joint -1): taken and run.
    s.expect(Command::New { count: 12 }, StatusCode::Ok);
    let start = s.plant.positions;
    let ack = s.pending(&points(start, 12, -1));
    assert_eq!(ack.status, StatusCode::Ok);
    s.expect(Command::Runing, StatusCode::Ok);
    s.plant.run(&mut s.controller, 100);
    assert_eq!(s.controller.state(), State::Stopped);
    assert_eq!(s.plant.positions[0], start[0] - 12, "jogged away");
    // The switch opens: further in is accepted again.
    s.controller.limit_switch(
        SwitchEvent::LimitReleased {
            joint: 0,
            side: Side::Max,
        },
        &mut s.plant,
    );
    s.expect(Command::New { count: 12 }, StatusCode::Ok);
    let ack = s.pending(&points(s.plant.positions, 12, 1));
    assert_eq!(ack.status, StatusCode::Ok);
}

#[test]
fn return_further_into_an_active_switch_is_refused_after_unlock() {
    let mut s = Session::<64>::new(64);
    s.set_location([-500; MAX_JOINTS]);
    s.controller.limit_switch(trip(1, Side::Max), &mut s.plant);
    s.expect(Command::Unlock, StatusCode::Ok);
    // Zero is +500 on joint 1: further into its max switch.
    s.expect(Command::Return, StatusCode::LimitLatched);
    s.controller.limit_switch(
        SwitchEvent::LimitReleased {
            joint: 1,
            side: Side::Max,
        },
        &mut s.plant,
    );
    s.expect(Command::Return, StatusCode::Ok);
}

#[test]
fn without_switches_nothing_changes() {
    let mut s = Session::<64>::new(64);
    s.expect(Command::Unlock, StatusCode::Ok);
    s.start_endless_run();
    assert_eq!(s.controller.hard_limits().latched(), None);
}
