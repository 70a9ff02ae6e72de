//! How a run that stopped early is explained, and the window a STATUS advertises.

use super::*;

fn ended(flags: u8, received: u16, executed: u16, total: usize) -> Error {
    let status = StatusReport {
        state: State::Stopped,
        flags: StatusFlags(flags),
        expected: total as u16,
        received,
        executed,
        ..StatusReport::default()
    };
    run_ended(Some(&status), total, None)
}

fn reason(e: &Error) -> RunEnd {
    match e {
        Error::RunEnded { reason, .. } => *reason,
        other => panic!("not RunEnded: {other}"),
    }
}

/// Bug 4 of issue 14: at time scale 20 with 1 ms segments a run ended with 8,000
/// points received and not run, and armctl said the upload was too slow.
#[test]
fn underrun_with_points_still_received_blames_the_controller() {
    let e = ended(StatusFlags::UNDERRUN, 9_000, 1_000, 20_000);
    assert_eq!(reason(&e), RunEnd::Starved, "{e}");
    let text = e.to_string();
    assert!(text.contains("8000"), "{text}");
    assert!(!text.contains("upload was too slow"), "{text}");
}

#[test]
fn underrun_with_every_received_point_run_blames_the_upload() {
    let e = ended(StatusFlags::UNDERRUN, 900, 900, 1_200);
    assert_eq!(reason(&e), RunEnd::Underrun, "{e}");
    assert!(e.to_string().contains("upload was too slow"), "{e}");
    // Everything arrived and ran, yet UNDERRUN: the controller's fault again.
    let e = ended(StatusFlags::UNDERRUN, 1_200, 1_199, 1_200);
    assert_eq!(reason(&e), RunEnd::Starved, "{e}");
}

#[test]
fn the_window_is_the_advertised_one_or_eight() {
    let status = |window| StatusReport {
        window,
        ..StatusReport::default()
    };
    assert_eq!(window_of(&status(0)), 8, "an old controller");
    assert_eq!(window_of(&status(32)), 32);
    assert_eq!(window_of(&status(4)), 4);
    assert_eq!(window_of(&status(1000)), MAX_WINDOW);
}

#[test]
fn stopped_wins_and_no_status_is_unknown() {
    let e = ended(
        StatusFlags::UNDERRUN | StatusFlags::STOPPED_BY_HOST,
        50,
        10,
        100,
    );
    assert_eq!(reason(&e), RunEnd::Stopped);
    assert_eq!(reason(&run_ended(None, 100, None)), RunEnd::Unknown);
}

/// Issue 31: a wired e-stop and a STOPPED from 127.0.0.2 both read "STOPPED was sent (by
/// this host or another)". With the stop cause the run's error names the input, or the
/// STOPPED's sender.
#[test]
fn the_stop_cause_names_the_input_or_the_stoppeds_sender() {
    let status = |cause| StatusReport {
        state: State::Stopped,
        flags: StatusFlags(StatusFlags::STOPPED_BY_HOST),
        more_flags: protocol::MoreFlags(protocol::MoreFlags::of_stop_cause(cause)),
        received: 50,
        executed: 10,
        ..StatusReport::default()
    };
    let e = run_ended(Some(&status(StopCause::EstopInput)), 100, None);
    assert_eq!(reason(&e), RunEnd::EstopInput);
    assert!(e.to_string().contains("wired e-stop input opened"), "{e}");
    let stop = StopReport {
        from_ip: [127, 0, 0, 2],
        from_port: 40_001,
        ..StopReport::of(StopCause::Stopped)
    };
    let e = run_ended(Some(&status(StopCause::Stopped)), 100, Some(&stop));
    assert_eq!(reason(&e), RunEnd::Stopped);
    assert!(
        e.to_string()
            .contains("STOPPED was sent by 127.0.0.2:40001"),
        "{e}"
    );
    let e = run_ended(Some(&status(StopCause::Underrun)), 100, None);
    assert_eq!(reason(&e), RunEnd::Starved, "received > executed");
    // Issue 32: an underrun with every received point run, controlled (detail 1) or dead.
    let mut s = status(StopCause::Underrun);
    s.received = 10;
    let stop = StopReport {
        detail: 1,
        ..StopReport::of(StopCause::Underrun)
    };
    let e = run_ended(Some(&s), 100, Some(&stop));
    assert_eq!(reason(&e), RunEnd::Underrun);
    assert!(matches!(
        e,
        Error::RunEnded {
            controlled: true,
            ..
        }
    ));
    assert!(e.to_string().contains("controlled underrun"), "{e}");
    assert!(crate::stop::stop_cause_text(&s, Some(&stop)).contains("controlled underrun"));
    let dead = StopReport::of(StopCause::Underrun);
    let e = run_ended(Some(&s), 100, Some(&dead));
    assert!(matches!(
        e,
        Error::RunEnded {
            controlled: false,
            ..
        }
    ));
    assert!(!e.to_string().contains("controlled"), "{e}");
    assert!(crate::stop::stop_cause_text(&s, Some(&dead)).contains("dead underrun"));
    // Issue 32: the safety door on a step side that cannot hold (STOP_CAUSE HOLD, DOOR).
    let door = StopReport {
        detail: protocol::ControlledStop::Door as u8,
        ..StopReport::of(StopCause::Hold)
    };
    let s = status(StopCause::Hold);
    assert!(crate::stop::stop_cause_text(&s, Some(&door)).contains("safety door"));
}

/// Issue 19's load test: under 20 % loss each way the window halved down to one frame, so
/// every later loss waited for an ACK timeout and a 4x run through 256 points underran
/// (3 of 6 runs with two busy loops per core). It stops at four frames.
#[test]
fn losses_never_shrink_the_window_below_four_frames() {
    let mut cwnd = 32.0;
    for _ in 0..10 {
        cwnd = upload::shrunk_window(cwnd, 32);
    }
    assert_eq!(cwnd, upload::MIN_LOSS_WINDOW as f64);
    assert_eq!(upload::shrunk_window(32.0, 32), 16.0);
    // A run asked for a smaller window keeps it.
    assert_eq!(upload::shrunk_window(2.0, 2), 2.0);
    assert_eq!(upload::shrunk_window(1.0, 1), 1.0);
}

/// Issue 33: a run cut by a limit switch ended "for a reason it did not say" (`unknown`).
/// The stop cause names the joint and the side, and how to go on.
#[test]
fn a_limit_switch_cut_names_the_joint_and_the_side() {
    let status = StatusReport {
        state: State::Stopped,
        more_flags: protocol::MoreFlags(protocol::MoreFlags::of_stop_cause(StopCause::LimitSwitch)),
        received: 50,
        executed: 10,
        ..StatusReport::default()
    };
    let stop = StopReport {
        detail: 0x80 | 2,
        ..StopReport::of(StopCause::LimitSwitch)
    };
    let e = run_ended(Some(&status), 100, Some(&stop));
    assert_eq!(reason(&e), RunEnd::LimitSwitch, "{e}");
    assert_eq!(RunEnd::LimitSwitch.name(), "limit_switch");
    let text = e.to_string();
    assert!(
        text.contains("joint 2") && text.contains("max") && text.contains("armctl unlock"),
        "{text}"
    );
    // An older report without the detail still names the cause.
    let e = run_ended(Some(&status), 100, None);
    assert_eq!(reason(&e), RunEnd::LimitSwitch, "{e}");
    assert!(e.to_string().contains("limit switch"), "{e}");
}
