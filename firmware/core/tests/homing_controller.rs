//! Issue 33, HOME in the sans-io controller (`controller/homing_run.rs`): refused
//! `HOMING_FAILED` without switch inputs or a joint set to home (nothing moves); the cycle
//! seeks, stops on the home switch's activation, backs off, approaches and sets the count
//! to the offset plus the steps made since the activation; STOPPED aborts it naming the
//! joint; a seek that travels its maximum fails naming the joint; HOMING_SET is a flash
//! write (deferred save).

mod common;

use arm_core::switches::SwitchEvent;
use common::*;
use protocol::{Command, HomingFailure, HomingPhase, HomingSet, HomingSettings, State, StatusCode};

fn settings() -> HomingSettings {
    HomingSettings {
        enabled: true,
        towards_max: false,
        switch_is_limit: false,
        order: 0,
        seek_rate_hz: 1_000,
        approach_rate_hz: 100,
        backoff_steps: 50,
        max_travel_steps: 1_000,
        offset: 7,
    }
}

fn homing_session() -> Session<64> {
    let mut s = Session::<64>::new(64);
    let mut stored = s.controller.settings();
    stored.homing[0] = settings();
    s.controller.apply_settings(stored);
    s.controller.set_switches_fitted(true);
    s
}

fn home(joint: u8, position: i32) -> SwitchEvent {
    SwitchEvent::HomeActive {
        joint,
        position,
        at_us: 0,
    }
}

#[test]
fn home_is_refused_without_switches_or_a_joint_set_to_home() {
    let mut s = Session::<64>::new(64);
    s.expect(Command::Home, StatusCode::HomingFailed);
    s.controller.set_switches_fitted(true);
    s.expect(Command::Home, StatusCode::HomingFailed);
    assert!(
        s.plant.queue.is_empty() && !s.plant.running,
        "nothing moved"
    );
    assert_eq!(s.controller.state(), State::Stopped);
    // HOMING_SET is a flash write: deferred, ACKed after the save.
    let response = s.send_raw(
        s.from,
        &frame(
            s.seq.wrapping_add(1),
            Command::HomingSet(HomingSet {
                joint: 0,
                settings: settings(),
            }),
        ),
    );
    assert!(matches!(
        response.deferred,
        Some(arm_core::Deferred::SaveSettings(stored)) if stored.homing[0] == settings()
    ));
}

#[test]
fn the_cycle_seeks_backs_off_approaches_and_sets_the_count_to_the_step() {
    let mut s = homing_session();
    s.plant.positions[0] = 400;
    s.expect(Command::Home, StatusCode::Ok);
    assert_eq!(s.controller.state(), State::Running);
    assert_eq!(s.plant.queue.front().map(|g| g.steps[0]), Some(-1_000));
    assert_eq!(s.controller.switches_report().phase, HomingPhase::Homing);
    // The switch closes at count 150; the stop comes 3 steps later.
    s.plant.positions[0] = 147;
    s.controller.limit_switch(home(0, 150), &mut s.plant);
    assert_eq!(
        s.plant.queue.front().map(|g| g.steps[0]),
        Some(50),
        "the back-off"
    );
    s.controller
        .limit_switch(SwitchEvent::HomeReleased { joint: 0 }, &mut s.plant);
    // The back-off's one segment runs dry: the approach starts.
    s.plant.run(&mut s.controller, 1);
    assert_eq!(s.plant.positions[0], 197);
    assert_eq!(
        s.plant.queue.front().map(|g| g.steps[0]),
        Some(-100),
        "the approach"
    );
    // The approach finds the switch at 149 and stops at 146.
    s.plant.positions[0] = 146;
    let location = s.controller.limit_switch(home(0, 149), &mut s.plant);
    assert_eq!(
        s.plant.positions[0],
        7 - 3,
        "offset plus the steps since the switch"
    );
    assert_eq!(s.controller.state(), State::Stopped);
    assert!(location.is_some(), "a LOCATION at the end");
    let report = s.controller.switches_report();
    assert_eq!(report.phase, HomingPhase::Homed);
    assert_eq!(report.homed, 1);
    assert_eq!(report.home_active, 1);
}

#[test]
fn stopped_aborts_the_cycle_and_a_seek_past_its_travel_fails_naming_the_joint() {
    let mut s = homing_session();
    s.expect(Command::Home, StatusCode::Ok);
    s.expect(Command::Stopped, StatusCode::Ok);
    let report = s.controller.switches_report();
    assert_eq!(report.phase, HomingPhase::Failed);
    assert_eq!(
        (report.joint, report.error),
        (0, Some(HomingFailure::Aborted))
    );
    assert!(!s.plant.running);
    // The whole travel without the switch.
    s.expect(Command::Home, StatusCode::Ok);
    s.plant.run_to_end(&mut s.controller);
    let report = s.controller.switches_report();
    assert_eq!(report.phase, HomingPhase::Failed);
    assert_eq!(
        (report.joint, report.error),
        (0, Some(HomingFailure::SeekTravel))
    );
    assert_eq!(s.controller.state(), State::Stopped);
    let stop = s.controller.stop_report();
    assert_eq!(stop.cause, Some(protocol::StopCause::Fault));
    assert_eq!(stop.detail, 0);
}
