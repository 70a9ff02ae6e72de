//! Issue 32: the safety-door input on the sans-io controller. Opening holds a run (HOLD's
//! ramp, MOTION's last stop DOOR, flag bit 4 door open); while open, RUNING and RESUME are
//! refused DOOR_OPEN; closing it and a RESUME go on. Idle, an open door refuses RUNING.

mod common;

use common::*;
use protocol::{
    Command, ControlledStop, MAX_JOINTS, MotionFlags, Point, State, StatusCode, StopCause,
};

/// 10 ms points of joint 0 at +4 steps from rest.
fn slow(n: usize) -> Vec<Point> {
    let mut at = [0i32; MAX_JOINTS];
    (0..n)
        .map(|_| {
            let before = at;
            at[0] += 4;
            Point::from_motion(10_000, &before, &at)
        })
        .collect()
}

#[test]
fn an_open_door_holds_the_run_and_a_resume_after_closing_goes_on() {
    let mut s = Session::<64>::new(64);
    let pts = slow(20);
    s.expect(Command::New { count: 20 }, StatusCode::Ok);
    for chunk in pts.chunks(10) {
        assert_eq!(s.pending(chunk).status, StatusCode::Ok);
    }
    s.expect(Command::Runing, StatusCode::Ok);
    s.plant.run(&mut s.controller, 2);
    assert_eq!(s.controller.door_input(true, &mut s.plant), None);
    assert_eq!(s.plant.rate_changes.len(), 1, "held");
    assert_eq!(s.plant.rate_changes[0].0, 0);
    let m = s.controller.motion_report(&s.plant);
    assert!(m.flags.has(MotionFlags::HELD | MotionFlags::DOOR_OPEN));
    assert_eq!(m.last_stop, Some(ControlledStop::Door));
    assert_eq!(s.controller.state(), State::Running);
    s.expect(Command::Resume, StatusCode::DoorOpen);
    s.expect(Command::Runing, StatusCode::DoorOpen);
    s.controller.door_input(false, &mut s.plant);
    assert!(
        !s.controller
            .motion_report(&s.plant)
            .flags
            .has(MotionFlags::DOOR_OPEN)
    );
    assert_eq!(
        s.plant.rate_changes.len(),
        1,
        "closing alone does not resume"
    );
    s.expect(Command::Resume, StatusCode::Ok);
    assert_eq!(s.plant.rate_changes.last().unwrap().0, arm_step::RATE_ONE);
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.controller.stop_report().cause, Some(StopCause::Complete));
    assert_eq!(s.plant.positions, pts[19].position);
}

#[test]
fn idle_an_open_door_refuses_runing_until_closed() {
    let mut s = Session::<64>::new(64);
    s.controller.door_input(true, &mut s.plant);
    assert!(
        s.controller
            .motion_report(&s.plant)
            .flags
            .has(MotionFlags::DOOR_OPEN)
    );
    s.expect(Command::New { count: 5 }, StatusCode::Ok);
    s.pending(&slow(5));
    s.expect(Command::Runing, StatusCode::DoorOpen);
    assert_eq!(s.controller.state(), State::Pending);
    assert_eq!(s.plant.starts, 0);
    s.controller.door_input(false, &mut s.plant);
    s.expect(Command::Runing, StatusCode::Ok);
    assert_eq!(s.controller.state(), State::Running);
}

/// On a step side without a warp (the NUCLEO's for now) an open door cannot hold the run:
/// it is stopped, and its stop cause says the door (HOLD with detail 3 DOOR), not the
/// wired e-stop input (which it said before: stop_by_host's cause for "no host").
#[test]
fn without_a_warp_the_door_stops_the_run_and_the_cause_says_so() {
    let mut s = Session::<64>::new(64);
    s.plant.warpless = true;
    let pts = slow(20);
    s.expect(Command::New { count: 20 }, StatusCode::Ok);
    for chunk in pts.chunks(10) {
        assert_eq!(s.pending(chunk).status, StatusCode::Ok);
    }
    s.expect(Command::Runing, StatusCode::Ok);
    s.plant.run(&mut s.controller, 2);
    let stops = s.plant.stops;
    let location = s.controller.door_input(true, &mut s.plant);
    assert!(location.is_some(), "a LOCATION of the state change");
    assert_eq!(s.plant.stops, stops + 1, "stopped at once");
    assert_eq!(s.controller.state(), State::Stopped);
    let stop = s.controller.stop_report();
    assert_eq!(stop.cause, Some(StopCause::Hold), "{stop:?}");
    assert_eq!(stop.detail, ControlledStop::Door as u8);
    assert!(!s.controller.estop_latched());
    s.expect(Command::Runing, StatusCode::DoorOpen);
}
