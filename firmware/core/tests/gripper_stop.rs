//! Issue 30 part 1, "a stop stops all motion", the gripper (docs/PROTOCOL.md, PWM_START):
//! a STOPPED (from any host) and the wired e-stop input cut a counted gripper burst, as
//! they stop the joints, and STATUS flag bit 6 then reads clear. A servo PWM keeps its
//! duty through a stop by default (a servo gripper that goes limp drops its part; bit 6
//! stays set, truthfully) and is cut with [`ServoOnStop::Cut`]. Before the change only
//! PWM_STOP (and the board's fault path) stopped the gripper: every burst test failed.

mod common;

use arm_core::ControllerConfig;
use arm_core::config::ServoOnStop;
use common::*;
use protocol::{Command, Pwm, State, StatusCode, StatusFlags, Tag};

/// The burst and a servo signal (one value with sim-host's gripper trials).
const BURST: Pwm = arm_core::test_support::GRIPPER_BURST;
const SERVO: Pwm = arm_core::test_support::GRIPPER_SERVO;

fn pwm_active(s: &Session<64>) -> bool {
    s.controller
        .status(&s.plant)
        .flags
        .has(StatusFlags::PWM_ACTIVE)
}

fn session(servo_on_stop: ServoOnStop) -> Session<64> {
    let mut s = Session::<64>::new(64);
    s.controller = arm_core::Controller::new(ControllerConfig {
        capacity: 64,
        servo_on_stop,
        ..ControllerConfig::BOARD
    });
    s
}

/// The stops the issue names, each applied to `s`.
#[derive(Clone, Copy, Debug)]
enum Stop {
    /// A STOPPED from a host that does not own the controller.
    StoppedFromAnotherHost,
    /// The owner's own STOPPED.
    StoppedFromTheOwner,
    /// The wired e-stop input opening.
    WiredInput,
}

const STOPS: [Stop; 3] = [
    Stop::StoppedFromAnotherHost,
    Stop::StoppedFromTheOwner,
    Stop::WiredInput,
];

fn apply(stop: Stop, s: &mut Session<64>) {
    match stop {
        Stop::StoppedFromAnotherHost => {
            let r = s.send_raw(OTHER, &raw(0x42, Tag::Stopped as u8, &[]));
            assert_eq!(r.reply.expect("an ACK").ack.status, StatusCode::Ok);
        }
        Stop::StoppedFromTheOwner => {
            s.expect(Command::Stopped, StatusCode::Ok);
        }
        Stop::WiredInput => {
            s.controller.estop_input(true, &mut s.plant);
        }
    }
}

#[test]
fn every_stop_cuts_a_gripper_burst_idle_or_running() {
    for stop in STOPS {
        for running in [false, true] {
            let mut s = session(ServoOnStop::Hold);
            if running {
                s.start_endless_run();
            }
            s.expect(Command::PwmStart(BURST), StatusCode::Ok);
            assert_eq!(s.plant.gripper, Some(BURST));
            assert!(pwm_active(&s));
            apply(stop, &mut s);
            assert_eq!(s.plant.gripper, None, "{stop:?}, running {running}");
            assert!(!pwm_active(&s), "{stop:?}: STATUS bit 6 clear");
            assert!(!s.plant.running, "{stop:?}: the joints stopped too");
            assert_eq!(s.controller.state(), State::Stopped);
        }
    }
}

#[test]
fn a_servo_holds_its_duty_through_every_stop_by_default() {
    for stop in STOPS {
        let mut s = session(ServoOnStop::Hold);
        s.start_endless_run();
        s.expect(Command::PwmStart(SERVO), StatusCode::Ok);
        let calls = s.plant.gripper_calls;
        apply(stop, &mut s);
        assert!(!s.plant.running, "{stop:?}: the joints stopped");
        assert_eq!(s.plant.gripper, Some(SERVO), "{stop:?}: still holding");
        assert_eq!(s.plant.gripper_calls, calls, "{stop:?}: not touched");
        assert!(pwm_active(&s), "{stop:?}: STATUS bit 6 tells it runs");
        // PWM_STOP still cuts it.
        s.expect(Command::PwmStop, StatusCode::Ok);
        assert_eq!(s.plant.gripper, None);
        assert!(!pwm_active(&s));
    }
}

#[test]
fn with_servo_on_stop_cut_every_stop_cuts_a_servo_too() {
    for stop in STOPS {
        let mut s = session(ServoOnStop::Cut);
        s.expect(Command::PwmStart(SERVO), StatusCode::Ok);
        apply(stop, &mut s);
        assert_eq!(s.plant.gripper, None, "{stop:?}");
        assert!(!pwm_active(&s), "{stop:?}: STATUS bit 6 clear");
    }
}

#[test]
fn a_servo_started_after_a_burst_holds_and_a_burst_after_a_servo_is_cut() {
    // The rule follows the output running at the stop, not an earlier start.
    let mut s = session(ServoOnStop::Hold);
    s.expect(Command::PwmStart(BURST), StatusCode::Ok);
    s.expect(Command::PwmStart(SERVO), StatusCode::Ok);
    apply(Stop::StoppedFromAnotherHost, &mut s);
    assert_eq!(s.plant.gripper, Some(SERVO));
    s.expect(Command::PwmStart(BURST), StatusCode::Ok);
    apply(Stop::StoppedFromAnotherHost, &mut s);
    assert_eq!(s.plant.gripper, None);
}

#[test]
fn a_burst_started_after_a_stop_runs() {
    // A stop is not a latch for the gripper: the next PWM_START works (the wired input's
    // latch refuses RUNING and RETURN only, section 4).
    for stop in STOPS {
        let mut s = session(ServoOnStop::Hold);
        s.expect(Command::PwmStart(BURST), StatusCode::Ok);
        apply(stop, &mut s);
        s.expect(Command::PwmStart(BURST), StatusCode::Ok);
        assert_eq!(s.plant.gripper, Some(BURST), "{stop:?}");
        assert!(pwm_active(&s));
    }
}

#[test]
fn a_stopped_that_overtook_a_pwm_start_cuts_the_burst_it_started() {
    // Arrival order: PWM_START, then STOPPED. The STOPPED was handled first (nothing ran);
    // the PWM_START, handled next, starts the burst, and the STOPPED applied after it
    // must cut it, although the state was STOPPED all along.
    let mut s = session(ServoOnStop::Hold);
    apply(Stop::StoppedFromAnotherHost, &mut s);
    s.expect(Command::PwmStart(BURST), StatusCode::Ok);
    assert_eq!(s.plant.gripper, Some(BURST));
    assert_eq!(s.controller.stop_after_overtaken(&mut s.plant), None);
    assert_eq!(s.plant.gripper, None, "the burst is cut");
    assert!(!pwm_active(&s));

    // A servo, by the same rule as any stop: held by default.
    s.expect(Command::PwmStart(SERVO), StatusCode::Ok);
    s.controller.stop_after_overtaken(&mut s.plant);
    assert_eq!(s.plant.gripper, Some(SERVO));
}

#[test]
fn a_burst_an_interrupt_already_cut_is_still_stopped_by_the_controller() {
    // The board's wired-input interrupt and receive path stop the timer itself before the
    // controller sees the stop: the controller's Gripper::stop must still come, to reset
    // the burst's bookkeeping (pulses not yet loaded, the reload interrupt).
    for stop in STOPS {
        let mut s = session(ServoOnStop::Hold);
        s.expect(Command::PwmStart(BURST), StatusCode::Ok);
        s.plant.gripper = None; // the interrupt's cut
        let calls = s.plant.gripper_calls;
        apply(stop, &mut s);
        assert_eq!(s.plant.gripper_calls, calls + 1, "{stop:?}");
        assert!(!pwm_active(&s));
    }
}
