//! RETURN when an absolute encoder does not answer: the ACK already said RUNNING, so the
//! outcome is a LOCATION in STOPPED, no motion, and the fault kept for STATUS and the log.

mod common;

use arm_core::Deferred;
use arm_core::hw::{EncoderFault, EncoderFaultKind};
use common::*;
use protocol::{Command, State, StatusCode, StatusFlags};

#[test]
fn a_failed_encoder_read_ends_return_in_stopped_without_moving() {
    let mut s = Session::<64>::new(64);
    s.set_location([500, -300, 0, 0, 0, 0, 0, 0]);
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(s.from, &frame(s.seq, Command::Return));
    assert_eq!(r.deferred, Some(Deferred::ReadEncoders));
    assert_eq!(s.controller.state(), State::Running);
    let fault = EncoderFault {
        joint: 1,
        kind: EncoderFaultKind::NoAnswer,
    };
    let loc = s
        .controller
        .fail_return(fault, &mut s.plant)
        .expect("LOCATION: the state changed");
    assert_eq!(loc.state, State::Stopped as u8);
    assert_eq!(loc.position[..2], [500, -300]);
    assert_eq!(s.controller.state(), State::Stopped);
    assert_eq!(s.controller.return_fault(), Some(fault));
    assert!(!s.plant.running && s.plant.starts == 0, "nothing moved");
    assert!(
        s.plant.set_positions_calls.len() <= 1,
        "positions not corrected"
    );
    let status = s.controller.status(&s.plant);
    assert!(!status.flags.has(StatusFlags::UNDERRUN));
    assert!(!status.flags.has(StatusFlags::STOPPED_BY_HOST));
    // A late reading changes nothing any more.
    assert!(
        s.controller
            .begin_return(Some([0; 8]), &mut s.plant)
            .is_none()
    );
    assert!(!s.plant.running);
    // The next RETURN clears the fault and works once the encoders answer.
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(s.from, &frame(s.seq, Command::Return));
    assert_eq!(r.deferred, Some(Deferred::ReadEncoders));
    assert_eq!(s.controller.return_fault(), None);
    s.controller
        .begin_return(Some([500, -300, 0, 0, 0, 0, 0, 0]), &mut s.plant);
    assert!(s.plant.running);
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.plant.positions[..2], [0, 0]);
}

#[test]
fn a_failed_return_after_a_run_reports_no_points_not_the_last_runs() {
    let mut s = Session::<64>::new(64);
    s.expect(Command::New { count: 3 }, StatusCode::Ok);
    assert_eq!(s.pending(&points([0; 8], 3, 1)).status, StatusCode::Ok);
    s.expect(Command::Runing, StatusCode::Ok);
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.controller.status(&s.plant).executed, 3);
    s.expect(Command::Return, StatusCode::Ok);
    let fault = EncoderFault {
        joint: 0,
        kind: EncoderFaultKind::Exception(2),
    };
    s.controller.fail_return(fault, &mut s.plant);
    let status = s.controller.status(&s.plant);
    assert_eq!((status.expected, status.executed), (0, 0));
    assert_eq!(s.controller.state(), State::Stopped);
}

#[test]
fn fail_return_outside_a_pending_return_does_nothing() {
    let mut s = Session::<64>::new(64);
    let fault = EncoderFault {
        joint: 0,
        kind: EncoderFaultKind::BadCrc,
    };
    assert!(s.controller.fail_return(fault, &mut s.plant).is_none());
    assert_eq!(s.controller.return_fault(), None);
    assert_eq!(s.controller.state(), State::Stopped);
}
