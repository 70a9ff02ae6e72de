//! Issue 14's link rules, sans-io: every CRC-valid STOPPED is executed (issue 18; was:
//! only an executed STOPPED stops, bug 1), the ordering
//! rule and the reports follow endpoints, not addresses (bug 2), and the smaller findings
//! (NOT_OWNER tells nothing, hand-over drops an unstarted upload, the advertised window).

mod common;

use arm_core::config::OWNER_TIMEOUT_US;
use arm_core::hw::Endpoint;
use arm_core::tasks::OvertakingStops;
use common::*;
use protocol::{Command, State, StatusCode, Tag};

use StatusCode::*;

/// A second tool on the owner's machine: same address, another port.
const TOOL: Endpoint = Endpoint {
    port: 40_999,
    ..HOST
};

// ---- Bug 1: only an executed STOPPED counts ----

#[test]
fn every_crc_valid_stopped_is_executed() {
    // Issue 18 reversed issue 14's rule here: a STOPPED with data was BAD_LENGTH and a
    // repeat within 2 s a duplicate, both "not executed". Now every CRC-valid STOPPED is
    // executed and ACKed OK.
    let mut s = Session::<16>::new(16);
    let r = s.send_raw(HOST, &raw(1, Tag::Stopped as u8, &[0]));
    assert_eq!((r.reply.unwrap().ack.status, r.executed), (Ok, true));
    let stop = frame(2, Command::Stopped);
    let r = s.send_raw(HOST, &stop);
    assert_eq!((r.reply.unwrap().ack.status, r.executed), (Ok, true));
    let r = s.send_raw(HOST, &stop);
    assert_eq!(
        (r.reply.unwrap().ack.status, r.executed),
        (Ok, true),
        "the same bytes again are executed again, not a duplicate"
    );
    let r = s.send_raw(OTHER, &raw(3, Tag::Stopped as u8, &[]));
    assert!(r.executed, "a stranger's STOPPED is executed");
    let mut bad = raw(4, Tag::Stopped as u8, &[]);
    *bad.last_mut().unwrap() ^= 1;
    let r = s.send_raw(OTHER, &bad);
    assert_eq!((r.reply.unwrap().ack.status, r.executed), (BadCrc, false));
}

#[test]
fn overtaking_stops_tell_executed_from_refused() {
    let mut stops = OvertakingStops::new();
    // Datagram stamped 0 arrived before STOPPED 0 (refused) and STOPPED 1 (executed).
    stops.took(false);
    assert!(!stops.executed_between(0, None));
    stops.took(true);
    assert!(stops.executed_between(0, None));
    assert!(
        !stops.executed_between(0, Some(1)),
        "only the refused one in 0..1"
    );
    assert!(stops.executed_between(1, Some(2)));
    assert!(!stops.executed_between(2, None), "arrived after both");
    assert!(!stops.executed_between(1, Some(1)), "empty range");
    // Far more refused STOPPEDs than the memory: an old executed one is still seen;
    // beyond the memory the answer is the safe one (stop).
    for _ in 0..100 {
        stops.took(false);
    }
    assert!(stops.executed_between(1, Some(2)));
    assert!(!stops.executed_between(2, None));
    for _ in 0..100 {
        stops.took(false);
    }
    assert!(
        stops.executed_between(1, Some(2)),
        "forgotten: counted as a stop"
    );
    // Wrapping stamps.
    let mut stops = OvertakingStops::new();
    for _ in 0..5 {
        stops.took(false);
    }
    assert!(!stops.executed_between(u32::MAX - 3, None));
}

// ---- Bug 2: the ordering rule counts only the uploader's endpoint ----

#[test]
fn a_second_tool_on_the_owners_address_does_not_move_next_seq() {
    let mut s = Session::<64>::new(64);
    let pts = points([0; 8], 4, 1);
    assert_eq!(
        s.send_raw(HOST, &frame(10, Command::New { count: 4 }))
            .reply
            .unwrap()
            .ack
            .status,
        Ok
    );
    let ack = s.send_raw(HOST, &pending(11, &pts[..2])).reply.unwrap().ack;
    assert_eq!((ack.status, ack.next_seq), (Ok, 12));
    // Another socket on the same machine polls STATUS with seq 12.
    let ack = s
        .send_raw(TOOL, &frame(12, Command::Status))
        .reply
        .unwrap()
        .ack;
    assert_eq!(ack.status, Ok);
    assert_eq!(
        s.controller.next_seq(),
        12,
        "the tool's seq is not the uploader's"
    );
    let ack = s.send_raw(HOST, &pending(12, &pts[2..])).reply.unwrap().ack;
    assert_eq!((ack.status, ack.next_seq), (Ok, 13), "{ack:?}");
    assert_eq!(s.controller.buffered(), 4, "no point lost");
}

#[test]
fn the_uploaders_own_commands_still_fill_gaps() {
    let mut s = Session::<64>::new(64);
    let pts = points([0; 8], 4, 1);
    s.send_raw(HOST, &frame(10, Command::New { count: 4 }));
    s.send_raw(HOST, &pending(11, &pts[..2]));
    s.send_raw(HOST, &frame(12, Command::Status));
    s.send_raw(TOOL, &frame(13, Command::Status));
    assert_eq!(s.controller.next_seq(), 13);
    let ack = s.send_raw(HOST, &pending(14, &pts[2..])).reply.unwrap().ack;
    assert_eq!((ack.status, ack.next_seq), (OutOfOrder, 13));
    let ack = s.send_raw(HOST, &pending(13, &pts[2..])).reply.unwrap().ack;
    assert_eq!(ack.status, Ok);
}

// ---- Bug 2: who gets which report ----

#[test]
fn status_answers_its_requester_and_location_keeps_going_to_the_uploader() {
    let mut s = Session::<64>::new(64);
    let pts = points([0; 8], 2, 1);
    s.send_raw(HOST, &frame(1, Command::New { count: 2 }));
    let r = s.send_raw(TOOL, &frame(7, Command::Status));
    assert_eq!(
        r.status.map(|(to, _)| to),
        Some(TOOL),
        "STATUS to its requester"
    );
    assert!(
        s.controller
            .report_settings()
            .location_goes_to(HOST, s.now_us)
    );
    s.send_raw(HOST, &pending(2, &pts));
    let r = s.send_raw(TOOL, &frame(8, Command::Status));
    assert_eq!(r.status.map(|(to, _)| to), Some(TOOL));
    let r = s.send_raw(HOST, &frame(3, Command::Runing));
    assert!(r.location.is_some());
    // The tool polls for a long time; the uploader waits silently for its run to end: it
    // keeps its LOCATIONs (it started the run).
    for k in 0..10 {
        s.now_us += 1_000_000;
        s.send_raw(TOOL, &frame(20 + k, Command::Status));
    }
    let settings = s.controller.report_settings();
    assert!(settings.location_goes_to(HOST, s.now_us), "{settings:?}");
    assert!(settings.location_goes_to(TOOL, s.now_us));
}

#[test]
fn usart_recv_goes_to_the_endpoint_that_opened_the_port() {
    let mut s = Session::<64>::new(64);
    s.send_raw(HOST, &frame(1, Command::Status));
    let init = protocol::UartInit {
        baud_rate: 115_200,
        ..Default::default()
    };
    let r = s.send_raw(TOOL, &frame(1, Command::UsartStart(init)));
    assert_eq!(r.reply.unwrap().ack.status, Ok);
    s.send_raw(HOST, &frame(2, Command::Status));
    assert_eq!(s.controller.report_settings().serial_to, Some(TOOL));
    assert!(
        s.controller
            .report_settings()
            .location_goes_to(HOST, s.now_us)
    );
}

#[test]
fn a_tool_gone_silent_gets_no_more_locations_and_a_new_one_gets_them_at_once() {
    let mut s = Session::<64>::new(64);
    s.send_raw(TOOL, &frame(1, Command::Status));
    // One-shot tools, one after the other (each a new socket): each gets LOCATIONs from
    // its first executed command on.
    let next = Endpoint {
        port: 41_500,
        ..HOST
    };
    s.send_raw(next, &frame(1, Command::Status));
    assert!(
        s.controller
            .report_settings()
            .location_goes_to(next, s.now_us)
    );
    s.now_us += OWNER_TIMEOUT_US;
    s.send_raw(HOST, &frame(2, Command::Status));
    let settings = s.controller.report_settings();
    assert!(settings.location_goes_to(HOST, s.now_us));
    assert!(
        !settings.location_goes_to(TOOL, s.now_us) && !settings.location_goes_to(next, s.now_us),
        "silent 5 s: dropped {settings:?}"
    );
    // Many tools: the one heard least recently makes room.
    for port in 0..6 {
        let e = Endpoint {
            port: 42_000 + port,
            ..HOST
        };
        s.now_us += 10;
        s.send_raw(e, &frame(1, Command::Status));
        assert!(s.controller.report_settings().location_goes_to(e, s.now_us));
    }
}

#[test]
fn a_tool_gone_silent_gets_no_more_locations_even_if_no_command_follows() {
    // Once the listener list was only pruned when a later command executed: a poller that
    // went away kept getting LOCATIONs for the whole of a long run nobody spoke during.
    let mut s = Session::<64>::new(64);
    let pts = points([0; 8], 2, 1);
    s.send_raw(HOST, &frame(1, Command::New { count: 2 }));
    s.send_raw(HOST, &pending(2, &pts));
    s.send_raw(HOST, &frame(3, Command::Runing));
    s.send_raw(TOOL, &frame(7, Command::Status));
    let settings = s.controller.report_settings();
    let heard_tool_us = s.now_us;
    let just_before = heard_tool_us + OWNER_TIMEOUT_US - 1;
    assert!(settings.location_goes_to(TOOL, just_before), "{settings:?}");
    let silent = heard_tool_us + OWNER_TIMEOUT_US;
    assert!(!settings.location_goes_to(TOOL, silent), "{settings:?}");
    // The uploader started the run: it keeps its reports however long it waits.
    let long_after = silent + 60 * OWNER_TIMEOUT_US;
    assert!(settings.location_goes_to(HOST, long_after));
    let mut encoder = arm_core::ReportEncoder::new();
    let mut buf = [0u8; arm_core::outgoing::MAX_REPORT_FRAME];
    let location = arm_core::Outgoing::Location(protocol::Location::default());
    let (to, _) = encoder
        .encode(&location, &settings, silent, &mut buf)
        .expect("a LOCATION for the uploader");
    assert_eq!(
        to.as_slice(),
        &[HOST],
        "sent 5 s after the tool's last frame"
    );
}

#[test]
fn a_lone_host_that_only_listens_keeps_its_locations() {
    // A host with one socket that turned reports on and then only listens, arm STOPPED:
    // it is the endpoint heard most recently, so reports keep coming, as under the manual,
    // for a minute of its silence.
    let mut s = Session::<64>::new(64);
    s.send_raw(HOST, &frame(1, Command::UploadStart));
    s.now_us += 1_000;
    s.send_raw(TOOL, &frame(1, Command::Status));
    // Issue 21 F6 bounded "keeps coming" to a minute of silence (it was for ever: one
    // forged datagram bought reports without end).
    use arm_core::reports::KEEPER_SILENCE_US;
    let settings = s.controller.report_settings();
    let later = s.now_us + KEEPER_SILENCE_US - 1;
    assert!(settings.location_goes_to(TOOL, later), "{settings:?}");
    assert!(
        !settings.location_goes_to(TOOL, later + 1),
        "a minute of silence ends them: {settings:?}"
    );
    assert!(
        !settings.location_goes_to(HOST, s.now_us + OWNER_TIMEOUT_US),
        "the other one, silent, is dropped: {settings:?}"
    );
    let mut s = Session::<64>::new(64);
    s.send_raw(HOST, &frame(1, Command::Status));
    let settings = s.controller.report_settings();
    assert!(settings.location_goes_to(HOST, s.now_us + KEEPER_SILENCE_US - 1));
}

#[test]
fn one_tool_gets_every_report_as_before() {
    let mut s = Session::<64>::new(64);
    let r = s.send_raw(HOST, &frame(1, Command::Status));
    assert_eq!(r.status.map(|(to, _)| to), Some(HOST));
    let settings = s.controller.report_settings();
    assert_eq!(
        (settings.location_to, settings.serial_to),
        ([Some(HOST), None, None, None], Some(HOST))
    );
}

// ---- Smaller findings ----

#[test]
fn a_not_owner_ack_tells_nothing() {
    let mut s = Session::<64>::new(64);
    let pts = points([0; 8], 2, 1);
    s.send_raw(HOST, &frame(1, Command::New { count: 4 }));
    s.send_raw(HOST, &pending(2, &pts));
    let ack = s
        .send_raw(OTHER, &frame(5, Command::UploadStart))
        .reply
        .unwrap()
        .ack;
    assert_eq!(ack.status, NotOwner);
    assert_eq!(
        (ack.state as u8, ack.next_seq, ack.buffered, ack.free),
        (0, 0, 0, 0),
        "{ack:?}"
    );
    // A read-only STATUS's ACK (issue 23) shows the state, never the next seq or the
    // buffer counts.
    let ack = s
        .send_raw(OTHER, &frame(5, Command::Status))
        .reply
        .unwrap()
        .ack;
    assert_eq!(
        (ack.status, ack.state, ack.next_seq, ack.buffered, ack.free),
        (Ok, protocol::State::Pending, 0, 0, 0),
        "{ack:?}"
    );
}

#[test]
fn hand_over_drops_an_unstarted_upload_and_says_so() {
    let mut s = Session::<64>::new(64);
    let pts = points([0; 8], 2, 1);
    s.send_raw(HOST, &frame(1, Command::New { count: 4 }));
    s.send_raw(HOST, &pending(2, &pts));
    assert_eq!(s.controller.state(), State::Pending);
    s.now_us += OWNER_TIMEOUT_US;
    let r = s.send_raw(OTHER, &frame(1, Command::Status));
    assert_eq!(r.reply.unwrap().ack.status, Ok);
    assert_eq!(
        s.controller.state(),
        State::Stopped,
        "the old upload is gone"
    );
    assert_eq!(s.controller.buffered(), 0);
    let (_, status) = r.status.unwrap();
    assert!(status.more_flags.has(protocol::MoreFlags::UPLOAD_DROPPED));
    let ack = s
        .send_raw(OTHER, &frame(2, Command::Runing))
        .reply
        .unwrap()
        .ack;
    assert_eq!(
        ack.status, BadState,
        "RUNING cannot start the old owner's half upload"
    );
    // A new upload clears the flag.
    s.send_raw(OTHER, &frame(3, Command::New { count: 1 }));
    let r = s.send_raw(OTHER, &frame(4, Command::Status));
    let more = r.status.unwrap().1.more_flags;
    assert!(!more.has(protocol::MoreFlags::UPLOAD_DROPPED));
}

#[test]
fn status_advertises_the_window() {
    let mut s = Session::<64>::new(64);
    let r = s.send_raw(HOST, &frame(1, Command::Status));
    let (_, status) = r.status.unwrap();
    assert_eq!(usize::from(status.window), arm_core::config::HOST_WINDOW);
    assert!(status.window >= 32);
}

#[test]
fn a_hand_over_that_drops_an_upload_reports_the_state_change_even_if_refused() {
    // Found by the fuzz target: the new owner's first frame is refused (here a NEW of 0
    // points: INVALID_CONFIG), yet the hand-over dropped the old owner's upload.
    let mut s = Session::<64>::new(64);
    s.send_raw(HOST, &frame(1, Command::New { count: 4 }));
    s.now_us += OWNER_TIMEOUT_US;
    let r = s.send_raw(OTHER, &frame(1, Command::New { count: 0 }));
    assert_eq!(r.reply.unwrap().ack.status, InvalidConfig);
    assert_eq!(s.controller.state(), State::Stopped);
    assert_eq!(
        r.location.map(|l| l.state),
        Some(State::Stopped as u8),
        "the state change is reported"
    );
}

#[test]
fn a_pending_from_another_endpoint_than_the_uploader_is_refused() {
    // Found by the fuzz target's "points are the uploader's" invariant.
    let mut s = Session::<64>::new(64);
    let pts = points([0; 8], 2, 1);
    s.send_raw(TOOL, &frame(1, Command::New { count: 4 }));
    let ack = s.send_raw(HOST, &pending(2, &pts)).reply.unwrap().ack;
    assert_eq!((ack.status, ack.state), (BadState, State::New));
    assert_eq!(s.controller.buffered(), 0);
    let ack = s.send_raw(TOOL, &pending(2, &pts)).reply.unwrap().ack;
    assert_eq!(ack.status, Ok);
}

// ---- Issue 21 F13: the duplicate memory is per endpoint ----

/// The owner's TOGGLE is ACKed but the ACK is lost; meanwhile a STATUS poller on the same
/// machine (another port) has 70 frames accepted within 2 s. The owner's resend must still
/// be recognised: with one shared memory of 64 frames it was forgotten and the TOGGLE ran
/// twice (the drivers back where they were; 5 of 5 in the audit).
#[test]
fn another_tools_frames_never_evict_the_owners_from_the_duplicate_memory() {
    let mut s = Session::<16>::new(16);
    s.expect(Command::Status, Ok);
    let toggle = frame(7, Command::ToggleEnablePins { mask: None });
    let r = s.send_raw(HOST, &toggle);
    assert_eq!(r.reply.unwrap().ack.status, Ok);
    let enabled = s.controller.enabled();
    for i in 0..70u32 {
        s.now_us += 1_000;
        let r = s.send_raw(TOOL, &frame(i as u8, Command::Status));
        assert_eq!(r.reply.unwrap().ack.status, Ok, "poll {i}");
    }
    let r = s.send_raw(HOST, &toggle);
    assert_eq!(r.reply.unwrap().ack.status, Ok);
    assert_eq!(
        s.controller.enabled(),
        enabled,
        "the resent TOGGLE is a duplicate: not executed again"
    );
}

// ---- Issue 21 F4: the end-of-run report reaches the endpoint that started the run ----

/// Whether `to` gets a LOCATION sent now (listed, and its time not up).
fn gets_location(s: &Session<16>, to: Endpoint) -> bool {
    let settings = s.controller.report_settings();
    settings
        .location_to
        .iter()
        .zip(settings.location_until_us)
        .any(|(l, until)| *l == Some(to) && s.now_us < until)
}

/// An uploader that starts a run of more than 5 s and then stays silent (it waits for the
/// end-of-run LOCATION) while a poller on its machine sends STATUS every second: at the
/// end the state is STOPPED, the poller was heard most recently, and the uploader, silent
/// for over 5 s, got no end-of-run report (5 of 5 in the audit). It keeps its reports for
/// 5 s after the run's end.
#[test]
fn a_silent_uploader_gets_the_end_of_run_report_while_another_tool_polls() {
    let mut s = Session::<16>::new(16);
    s.start_run(8, &points([0; 8], 8, 1));
    for _ in 0..7 {
        s.now_us += 1_000_000;
        let r = s.send_raw(TOOL, &frame(1, Command::Status));
        assert_eq!(r.reply.unwrap().ack.status, Ok);
        assert!(
            gets_location(&s, HOST),
            "the uploader keeps reports while it runs"
        );
    }
    let end = s
        .plant
        .run_to_end(&mut s.controller)
        .expect("the end-of-run LOCATION");
    assert_eq!(end.state, State::Stopped as u8);
    assert!(
        gets_location(&s, HOST),
        "the end-of-run report goes to the uploader"
    );
    assert!(gets_location(&s, TOOL), "and to the poller");
    // Afterwards the uploader's 5 s of silence count from the run's end.
    s.now_us += OWNER_TIMEOUT_US + 1;
    let r = s.send_raw(TOOL, &frame(2, Command::Status));
    assert_eq!(r.reply.unwrap().ack.status, Ok);
    assert!(
        !gets_location(&s, HOST),
        "a silent uploader's reports end 5 s after the run"
    );
}

// ---- Issue 21 F6: one datagram buys a bounded volume of reports ----

/// One forged 3-byte STATUS to an unowned controller made the victim the owner and sent it
/// LOCATION reports (about 92 a second) indefinitely: as the endpoint heard most recently
/// it kept them however long it was silent. Now, while nothing runs, the endpoint heard
/// most recently keeps them for a minute of silence (a host that only listens, as under
/// the manual), any other for 5 s: one datagram buys at most a minute of reports.
#[test]
fn one_forged_datagram_buys_at_most_a_minute_of_reports() {
    use arm_core::reports::KEEPER_SILENCE_US;
    let mut s = Session::<16>::new(16);
    let r = s.send_raw(HOST, &frame(1, Command::Status));
    assert_eq!(r.reply.unwrap().ack.status, Ok);
    assert!(gets_location(&s, HOST), "reports at once");
    s.now_us += KEEPER_SILENCE_US - 1;
    assert!(gets_location(&s, HOST), "for a minute");
    s.now_us += 1;
    assert!(!gets_location(&s, HOST), "and no longer");
    // Speaking again brings them back.
    let r = s.send_raw(HOST, &frame(2, Command::Status));
    assert_eq!(r.reply.unwrap().ack.status, Ok);
    assert!(gets_location(&s, HOST));
}

/// The end-of-run report reaches an uploader that stayed silent through a run longer than
/// a minute with nobody else speaking: the run's end counts from when it ends (the
/// trajectory task tells the controller the time), not from the uploader's last frame.
#[test]
fn a_long_silent_run_still_reports_its_end_to_its_uploader() {
    let mut s = Session::<16>::new(16);
    s.start_run(8, &points([0; 8], 8, 1));
    s.now_us += 70_000_000;
    s.controller.note_time(s.now_us);
    let end = s
        .plant
        .run_to_end(&mut s.controller)
        .expect("the end-of-run LOCATION");
    assert_eq!(end.state, State::Stopped as u8);
    assert!(
        gets_location(&s, HOST),
        "the end-of-run report goes to the uploader"
    );
}
