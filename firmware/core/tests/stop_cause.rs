//! Issue 31, "the stop cause is told": STATUS says what ended the last run (`more_flags`
//! bits 5-7) and the STOP_CAUSE report (STATUS request byte bit 2) who sent the STOPPED.
//! Before it a wired e-stop and a STOPPED from 127.0.0.2 gave the same STATUS (flag bit 7,
//! "STOPPED was sent"), byte for byte.

mod common;

use arm_core::Deferred;
use arm_core::hw::{EncoderFault, EncoderFaultKind, Endpoint};
use common::*;
use protocol::{
    Command, MAX_JOINTS, Report, State, StatusAsk, StatusCode, StatusFlags, StatusReport,
    StopCause, StopReport,
};

/// The STATUS report's bytes (what every host decodes).
fn status_bytes(s: &Session<64>) -> Vec<u8> {
    let mut buf = [0u8; 64];
    let n = Report::Status(s.controller.status(&s.plant))
        .encode(0, &mut buf)
        .expect("encodes");
    buf[..n].to_vec()
}

fn status(s: &Session<64>) -> StatusReport {
    s.controller.status(&s.plant)
}

/// The STOP_CAUSE report `from` gets for a STATUS with request byte bit 2.
fn ask_stop(s: &mut Session<64>, from: Endpoint) -> StopReport {
    s.seq = s.seq.wrapping_add(1);
    let ask = StatusAsk {
        stop_cause: true,
        ..StatusAsk::default()
    };
    let r = s.send_raw(from, &frame(s.seq, Command::StatusWith(ask)));
    assert_eq!(r.reply.map(|r| r.ack.status), Some(StatusCode::Ok));
    let (to, stop) = r.asked_stop.expect("a STOP_CAUSE report");
    assert_eq!(to, from, "to the asker");
    stop
}

#[test]
fn a_wired_estop_and_a_stopped_from_another_host_read_differently() {
    let mut by_input = Session::<64>::new(64);
    by_input.start_endless_run();
    by_input.controller.estop_input(true, &mut by_input.plant);
    by_input.controller.estop_input(false, &mut by_input.plant);
    by_input.expect(Command::EstopReset, StatusCode::Ok);

    let mut by_host = Session::<64>::new(64);
    by_host.start_endless_run();
    let r = by_host.send_raw(OTHER, &frame(9, Command::Stopped));
    assert_eq!(r.reply.map(|r| r.ack.status), Some(StatusCode::Ok));

    // Old hosts' view is unchanged: flag bit 7 in both.
    for s in [&by_input, &by_host] {
        assert!(status(s).flags.has(StatusFlags::STOPPED_BY_HOST));
        assert_eq!(s.controller.state(), State::Stopped);
    }
    assert_ne!(
        status_bytes(&by_input),
        status_bytes(&by_host),
        "STATUS must tell the wired input from a STOPPED"
    );
    assert_eq!(status(&by_input).stop_cause(), Some(StopCause::EstopInput));
    assert_eq!(status(&by_host).stop_cause(), Some(StopCause::Stopped));

    let stop = ask_stop(&mut by_host, HOST);
    assert_eq!(stop.cause, Some(StopCause::Stopped));
    assert_eq!((stop.from_ip, stop.from_port), (OTHER.ip, OTHER.port));
    let stop = ask_stop(&mut by_input, HOST);
    assert_eq!(stop, StopReport::of(StopCause::EstopInput));
}

#[test]
fn boot_completion_and_underrun_are_told() {
    let mut s = Session::<64>::new(64);
    assert_eq!(status(&s).stop_cause(), Some(StopCause::Complete));
    s.start_run(2, &points([0; MAX_JOINTS], 2, 1));
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(status(&s).stop_cause(), Some(StopCause::Complete));
    s.start_run(5, &points([2; MAX_JOINTS], 2, 1));
    s.plant.run_to_end(&mut s.controller);
    let st = status(&s);
    assert_eq!(st.stop_cause(), Some(StopCause::Underrun));
    assert!(st.flags.has(StatusFlags::UNDERRUN));
    assert_eq!(ask_stop(&mut s, HOST), StopReport::of(StopCause::Underrun));
}

#[test]
fn a_stopped_with_nothing_running_leaves_the_cause_and_a_run_clears_it() {
    let mut s = Session::<64>::new(64);
    s.start_endless_run();
    s.send_raw(OTHER, &frame(9, Command::Stopped));
    // A second STOPPED, from the owner, with nothing under way: the first stays the cause.
    s.send_raw(HOST, &frame(10, Command::Stopped));
    let stop = ask_stop(&mut s, HOST);
    assert_eq!(stop.from_ip, OTHER.ip);
    s.seq = 10;
    s.start_run(2, &points(s.plant.positions, 2, 1));
    assert_eq!(
        status(&s).stop_cause(),
        Some(StopCause::Complete),
        "a run clears it"
    );
}

#[test]
fn a_failed_return_is_a_fault_naming_the_joint() {
    let mut s = Session::<64>::new(64);
    s.set_location([500, -300, 0, 0, 0, 0, 0, 0]);
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(s.from, &frame(s.seq, Command::Return));
    assert_eq!(r.deferred, Some(Deferred::ReadEncoders));
    let fault = EncoderFault {
        joint: 4,
        kind: EncoderFaultKind::NoAnswer,
    };
    s.controller.fail_return(fault, &mut s.plant);
    let st = status(&s);
    assert_eq!(st.stop_cause(), Some(StopCause::Fault));
    assert!(!st.flags.has(StatusFlags::STOPPED_BY_HOST) && !st.flags.has(StatusFlags::UNDERRUN));
    let stop = ask_stop(&mut s, HOST);
    assert_eq!((stop.cause, stop.detail), (Some(StopCause::Fault), 4));
}

#[test]
fn a_read_only_status_gets_the_stop_cause_with_its_own_seq() {
    let mut s = Session::<64>::new(64);
    s.start_endless_run();
    s.send_raw(OTHER, &frame(9, Command::Stopped));
    let ask = StatusAsk {
        look_only: true,
        stop_cause: true,
        ..StatusAsk::default()
    };
    let r = s.send_raw(OTHER, &frame(0x42, Command::StatusWith(ask)));
    assert_eq!(r.answer_seq, Some(0x42), "read-only");
    let (to, stop) = r.asked_stop.expect("a STOP_CAUSE report");
    assert_eq!((to, stop.from_ip), (OTHER, OTHER.ip));
}

#[test]
fn a_stop_after_overtaken_frames_keeps_the_stoppers_address() {
    let mut s = Session::<64>::new(64);
    s.expect(Command::New { count: 3 }, StatusCode::Ok);
    s.pending(&points([0; MAX_JOINTS], 3, 1));
    // The STOPPED from OTHER was handled first (it overtook the RUNING in the inbox).
    s.send_raw(OTHER, &frame(9, Command::Stopped));
    s.expect(Command::New { count: 3 }, StatusCode::Ok);
    s.pending(&points([0; MAX_JOINTS], 3, 1));
    s.expect(Command::Runing, StatusCode::Ok);
    s.controller.stop_after_overtaken(&mut s.plant);
    let stop = ask_stop(&mut s, HOST);
    assert_eq!(stop.cause, Some(StopCause::Stopped));
    assert_eq!((stop.from_ip, stop.from_port), (OTHER.ip, OTHER.port));
}
