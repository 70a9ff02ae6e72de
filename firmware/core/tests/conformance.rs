//! A third-party host writer's audit: rules of PROTOCOL.md that the other tests leave
//! loose, each pinned by a test that fails if the rule breaks.

mod common;

use arm_core::config::{DUPLICATE_MEMORY, DUPLICATE_WINDOW_US, OWNER_TIMEOUT_US};
use arm_core::hw::{Endpoint, PersistentSettings};
use common::*;
use protocol::{
    Command, Location, Point, Pwm, Report, State, StatusCode, StatusFlags, Tag, UartInit,
};

use StatusCode::*;

fn status_of(r: &arm_core::Response) -> StatusCode {
    r.reply.expect("an ACK").ack.status
}

// ---- docs/PROTOCOL.md, "Transport and ownership" ----

#[test]
fn a_host_keeps_ownership_by_sending_status() {
    let mut s = Session::<16>::new(16);
    s.expect(Command::Status, Ok);
    // Every 4 s a STATUS: the owner is never silent for 5 s.
    for i in 0..5u8 {
        s.now_us += OWNER_TIMEOUT_US - 1_000_000;
        s.expect(Command::Status, Ok);
        let r = s.send_raw(OTHER, &frame(100 + i, Command::UploadStart));
        assert_eq!(status_of(&r), NotOwner, "round {i}");
        // Its STATUS is answered read-only (issue 23), taking nothing.
        let r = s.send_raw(OTHER, &frame(100 + i, Command::Status));
        assert_eq!((status_of(&r), r.answer_seq), (Ok, Some(100 + i)));
    }
    assert_eq!(s.controller.owner().map(|o| o.ip), Some(HOST.ip));
}

#[test]
fn a_refused_frame_from_the_owner_also_counts_as_sending() {
    let mut s = Session::<16>::new(16);
    s.expect(Command::Status, Ok);
    s.now_us += OWNER_TIMEOUT_US - 1_000_000;
    s.expect(Command::Runing, BadState);
    s.now_us += 1_500_000;
    let r = s.send_raw(OTHER, &frame(1, Command::UploadStart));
    assert_eq!(status_of(&r), NotOwner, "owner spoke 1.5 s ago");
}

#[test]
fn a_strangers_stopped_changes_neither_owner_nor_report_port_nor_silence() {
    let mut s = Session::<16>::new(16);
    s.expect(Command::Status, Ok);
    s.now_us += OWNER_TIMEOUT_US - 1_000_000;
    let r = s.send_raw(OTHER, &frame(200, Command::Stopped));
    let reply = r.reply.expect("an ACK");
    assert_eq!((reply.to, reply.seq, reply.ack.status), (OTHER, 200, Ok));
    let owner = s.controller.owner().expect("an owner");
    assert_eq!(owner.ip, HOST.ip);
    assert_eq!(
        s.controller.report_settings().location_to,
        [Some(HOST), None, None, None],
        "reports stay with the owner"
    );
    // The stranger's STOPPED did not refresh the owner's silence: 1 s later the owner has
    // been silent 5 s, and the stranger may take over.
    s.now_us += 1_000_000;
    let r = s.send_raw(OTHER, &frame(201, Command::Status));
    assert_eq!(status_of(&r), Ok);
    assert_eq!(
        s.controller.report_settings().location_to,
        [Some(OTHER), None, None, None]
    );
}

#[test]
fn a_strangers_stopped_does_not_fill_a_gap_in_the_upload() {
    let mut s = Session::<16>::new(16);
    s.send_raw(HOST, &frame(10, Command::New { count: 4 }));
    // The owner's PENDING 11 is lost; a stranger's STOPPED happens to carry seq 11.
    let r = s.send_raw(OTHER, &frame(11, Command::Stopped));
    assert_eq!(status_of(&r), Ok);
    s.send_raw(HOST, &frame(12, Command::New { count: 4 }));
    let r = s.send_raw(OTHER, &frame(13, Command::Stopped));
    assert_eq!(status_of(&r), Ok);
    s.send_raw(HOST, &frame(14, Command::New { count: 4 }));
    // 15 lost, a stranger's frame with 15 is refused (NOT_OWNER): it fills nothing;
    // nor does its STATUS with 15, answered read-only (issue 23).
    let r = s.send_raw(OTHER, &frame(15, Command::UploadStart));
    assert_eq!(status_of(&r), NotOwner);
    let r = s.send_raw(OTHER, &frame(15, Command::Status));
    assert_eq!((status_of(&r), r.answer_seq), (Ok, Some(15)));
    let r = s.send_raw(HOST, &pending(16, &points([0; 8], 1, 1)));
    let ack = r.reply.expect("an ACK").ack;
    assert_eq!((ack.status, ack.next_seq), (OutOfOrder, 15));
}

#[test]
fn a_bad_crc_never_takes_over_or_refreshes() {
    let mut s = Session::<16>::new(16);
    s.expect(Command::Status, Ok);
    s.now_us += OWNER_TIMEOUT_US;
    let mut bad = frame(5, Command::Status);
    *bad.last_mut().unwrap() ^= 1;
    let r = s.send_raw(OTHER, &bad);
    assert_eq!(status_of(&r), BadCrc);
    assert_eq!(s.controller.owner().map(|o| o.ip), Some(HOST.ip));
    // Nor does a bad CRC from the owner count as it speaking... but a valid frame does.
    let mut bad_own = frame(6, Command::Status);
    *bad_own.last_mut().unwrap() ^= 1;
    assert_eq!(status_of(&s.send_raw(HOST, &bad_own)), BadCrc);
    let r = s.send_raw(OTHER, &frame(7, Command::Status));
    assert_eq!(
        status_of(&r),
        Ok,
        "owner silent 5 s: the stranger takes over"
    );
}

#[test]
fn not_owner_comes_before_decode_errors_and_duplicates() {
    let mut s = Session::<16>::new(16);
    s.expect(Command::Status, Ok);
    let r = s.send_raw(OTHER, &raw(1, 0x02, &[1]));
    assert_eq!(status_of(&r), NotOwner, "bad length from a stranger");
    let r = s.send_raw(OTHER, &raw(2, 0x40, &[]));
    assert_eq!(status_of(&r), NotOwner, "unknown tag from a stranger");
    // A stranger's STOPPED with data stops (issue 18 reversed the old rule, under which
    // it was BAD_LENGTH: the data is ignored, an e-stop is never refused for its length).
    let r = s.send_raw(OTHER, &raw(3, Tag::Stopped as u8, &[0]));
    assert_eq!(status_of(&r), Ok);
}

#[test]
fn every_ack_and_status_goes_to_its_sender_and_location_to_each_tool() {
    let mut s = Session::<16>::new(16);
    let a = Endpoint {
        port: 5_001,
        ..HOST
    };
    let b = Endpoint {
        port: 5_002,
        ..HOST
    };
    let r = s.send_raw(a, &frame(1, Command::Status));
    assert_eq!(r.reply.map(|r| r.to), Some(a));
    assert_eq!(r.status.map(|(to, _)| to), Some(a));
    assert!(s.controller.report_settings().location_goes_to(a, s.now_us));
    let r = s.send_raw(b, &frame(2, Command::Status));
    assert_eq!(r.reply.map(|r| r.to), Some(b));
    assert_eq!(
        r.status.map(|(to, _)| to),
        Some(b),
        "STATUS report goes to b"
    );
    let settings = s.controller.report_settings();
    assert!(
        settings.location_goes_to(a, s.now_us) && settings.location_goes_to(b, s.now_us),
        "b's STATUS does not take LOCATION away from a: both get it"
    );
    // A stranger's STOPPED is ACKed to the stranger; its LOCATION goes to the owner's
    // tools, not to the stranger.
    s.send_raw(b, &frame(3, Command::New { count: 1 }));
    let r = s.send_raw(OTHER, &frame(9, Command::Stopped));
    assert_eq!(r.reply.map(|r| r.to), Some(OTHER));
    assert_eq!(r.location.map(|l| l.state), Some(State::Stopped as u8));
    let settings = s.controller.report_settings();
    assert!(settings.location_goes_to(a, s.now_us) && settings.location_goes_to(b, s.now_us));
    assert!(!settings.location_goes_to(OTHER, s.now_us));
}

// ---- docs/PROTOCOL.md, "Ordering, retransmission and duplicates" ----

#[test]
fn next_seq_wraps_from_255_to_0_with_interleaved_commands() {
    let mut s = Session::<32>::new(32);
    let pts = points([0; 8], 4, 1);
    let r = s.send_raw(HOST, &frame(253, Command::New { count: 4 }));
    assert_eq!(r.reply.unwrap().ack.next_seq, 254);
    let r = s.send_raw(HOST, &pending(254, &pts[0..1]));
    assert_eq!(r.reply.unwrap().ack.next_seq, 255);
    // 255: a STATUS, 0: a PIN command, both accepted: PENDING 1 is in order.
    assert_eq!(
        status_of(&s.send_raw(HOST, &frame(255, Command::Status))),
        Ok
    );
    let r = s.send_raw(HOST, &frame(0, Command::Pin0On));
    assert_eq!(r.reply.unwrap().ack.next_seq, 1);
    let r = s.send_raw(HOST, &pending(1, &pts[1..2]));
    assert_eq!(r.reply.unwrap().ack.next_seq, 2);
    // PENDING 2 lost; 3 is refused and names 2.
    let r = s.send_raw(HOST, &pending(3, &pts[2..3]));
    let ack = r.reply.unwrap().ack;
    assert_eq!((ack.status, ack.next_seq), (OutOfOrder, 2));
    assert_eq!(s.controller.buffered(), 2);
}

#[test]
fn a_late_duplicate_never_lets_a_lost_pending_be_skipped_a_lap_later() {
    let mut s = Session::<512>::new(512);
    let pts = points([0; 8], 300, 1);
    s.send_raw(HOST, &frame(10, Command::New { count: 300 }));
    let first = pending(11, &pts[0..1]);
    assert_eq!(status_of(&s.send_raw(HOST, &first)), Ok);
    assert_eq!(status_of(&s.send_raw(HOST, &pending(12, &pts[1..2]))), Ok);
    // The host's resend of 11 (its ACK was lost) arrives after 12: a duplicate.
    assert_eq!(status_of(&s.send_raw(HOST, &first)), Ok);
    assert_eq!(s.controller.buffered(), 2, "not taken twice");
    // Streaming goes on one point per frame through a whole lap of seqs, up to 10.
    let mut next = 2;
    let mut seq = 13u8;
    while seq != 11 {
        let r = s.send_raw(HOST, &pending(seq, &pts[next..next + 1]));
        assert_eq!(status_of(&r), Ok, "seq {seq}");
        next += 1;
        seq = seq.wrapping_add(1);
    }
    // This lap's PENDING 11 is lost: 12 must be refused, not taken over the gap.
    let r = s.send_raw(HOST, &pending(12, &pts[next + 1..next + 2]));
    let ack = r.reply.unwrap().ack;
    assert_eq!((ack.status, ack.next_seq), (OutOfOrder, 11));
    assert_eq!(s.controller.buffered(), next);
}

#[test]
fn any_number_of_commands_may_be_interleaved_between_pendings() {
    for interleaved in [254usize, 255, 256, 300, 700] {
        let mut s = Session::<16>::new(16);
        let pts = points([0; 8], 3, 1);
        s.send_raw(HOST, &frame(10, Command::New { count: 3 }));
        assert_eq!(status_of(&s.send_raw(HOST, &pending(11, &pts[0..1]))), Ok);
        // A host polling STATUS while it waits to send more points.
        let mut seq = 11u8;
        for _ in 0..interleaved {
            seq = seq.wrapping_add(1);
            let r = s.send_raw(HOST, &frame(seq, Command::Status));
            assert_eq!(status_of(&r), Ok);
        }
        let r = s.send_raw(HOST, &pending(seq.wrapping_add(1), &pts[1..2]));
        let ack = r.reply.unwrap().ack;
        assert_eq!(
            (ack.status, ack.next_seq),
            (Ok, seq.wrapping_add(2)),
            "{interleaved} commands in between"
        );
        // And the rule still holds after it: a lost PENDING is not skipped.
        let r = s.send_raw(HOST, &pending(seq.wrapping_add(3), &pts[2..3]));
        let ack = r.reply.unwrap().ack;
        assert_eq!(
            (ack.status, ack.next_seq),
            (OutOfOrder, seq.wrapping_add(2))
        );
        assert_eq!(s.controller.buffered(), 2);
    }
}

#[test]
fn a_late_command_from_before_new_never_lets_a_lost_pending_be_skipped() {
    let mut s = Session::<512>::new(512);
    let pts = points([0; 8], 300, 1);
    s.send_raw(HOST, &frame(10, Command::New { count: 300 }));
    // The host sent STATUS 9 just before NEW 10; the network delivered it after.
    assert_eq!(status_of(&s.send_raw(HOST, &frame(9, Command::Status))), Ok);
    let mut next = 0;
    let mut seq = 11u8;
    while seq != 8 {
        let r = s.send_raw(HOST, &pending(seq, &pts[next..next + 1]));
        assert_eq!(status_of(&r), Ok, "seq {seq}");
        next += 1;
        seq = seq.wrapping_add(1);
    }
    // A lap later PENDING 8 is lost: 9 is refused, the host resends 8 and then 9.
    let p8 = pending(8, &pts[next..next + 1]);
    let p9 = pending(9, &pts[next + 1..next + 2]);
    let ack = s.send_raw(HOST, &p9).reply.unwrap().ack;
    assert_eq!((ack.status, ack.next_seq), (OutOfOrder, 8));
    assert_eq!(status_of(&s.send_raw(HOST, &p8)), Ok);
    let ack = s.send_raw(HOST, &p9).reply.unwrap().ack;
    assert_eq!(
        (ack.status, ack.next_seq),
        (Ok, 10),
        "PENDING 9 taken, not skipped"
    );
    assert_eq!(s.controller.buffered(), next + 2);
}

#[test]
fn duplicates_are_remembered_2_s_and_only_the_last_duplicate_memory() {
    let mut s = Session::<16>::new(16);
    let pin = frame(7, Command::Pin0On);
    s.send_raw(HOST, &pin);
    s.now_us += DUPLICATE_WINDOW_US - 100;
    assert_eq!(status_of(&s.send_raw(HOST, &pin)), Ok);
    assert_eq!(s.plant.pins.len(), 1, "within 2 s: not executed again");
    // DUPLICATE_MEMORY - 1 more accepted frames: PIN0_ON 7 is still remembered.
    let mut s = Session::<16>::new(16);
    s.send_raw(HOST, &pin);
    for seq in 8..8 + DUPLICATE_MEMORY as u8 - 1 {
        s.send_raw(HOST, &frame(seq, Command::Status));
    }
    s.send_raw(HOST, &pin);
    assert_eq!(s.plant.pins.len(), 1, "still remembered");
    // One more: it is forgotten and executed again.
    s.send_raw(HOST, &frame(100, Command::Status));
    s.send_raw(HOST, &pin);
    assert_eq!(
        s.plant.pins.len(),
        2,
        "forgotten after DUPLICATE_MEMORY newer frames"
    );
}

#[test]
fn a_refused_frame_is_not_a_duplicate_and_a_duplicate_skips_the_state_check() {
    let mut s = Session::<16>::new(16);
    // RUNING refused in STOPPED; the same bytes later are executed.
    let runing = frame(3, Command::Runing);
    assert_eq!(status_of(&s.send_raw(HOST, &runing)), BadState);
    s.send_raw(HOST, &frame(1, Command::New { count: 1 }));
    s.send_raw(HOST, &pending(2, &points([0; 8], 1, 1)));
    assert_eq!(status_of(&s.send_raw(HOST, &runing)), Ok);
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.controller.state(), State::Stopped);
    // Resent after the run ended: a duplicate, ACKed OK (not BAD_STATE), not executed.
    let starts = s.plant.starts;
    assert_eq!(status_of(&s.send_raw(HOST, &runing)), Ok);
    assert_eq!(
        (s.plant.starts, s.controller.state()),
        (starts, State::Stopped)
    );
}

// ---- docs/PROTOCOL.md, "Commands (host to controller)" ----

#[test]
fn stopped_in_idle_keeps_how_the_last_run_ended() {
    let mut s = Session::<16>::new(16);
    s.start_run(5, &points([0; 8], 2, 1));
    s.plant.run_to_end(&mut s.controller);
    let flags = s.controller.status(&s.plant).flags;
    assert!(flags.has(StatusFlags::UNDERRUN));
    // A STOPPED after the run ended (e.g. a host's stop button) ends no run.
    s.expect(Command::Stopped, Ok);
    let flags = s.controller.status(&s.plant).flags;
    assert!(
        flags.has(StatusFlags::UNDERRUN),
        "the last run still ended by underrun"
    );
    assert!(!flags.has(StatusFlags::STOPPED_BY_HOST));
    // A STOPPED that drops an upload (PENDING) ends that trajectory: bit 7.
    s.expect(Command::New { count: 1 }, Ok);
    s.pending(&points(s.plant.positions, 1, 1));
    s.expect(Command::Stopped, Ok);
    let flags = s.controller.status(&s.plant).flags;
    assert!(flags.has(StatusFlags::STOPPED_BY_HOST) && !flags.has(StatusFlags::UNDERRUN));
    // A run that completes, then a STOPPED: neither bit.
    s.start_run(1, &points(s.plant.positions, 1, 1));
    s.plant.run_to_end(&mut s.controller);
    s.expect(Command::Stopped, Ok);
    let flags = s.controller.status(&s.plant).flags;
    assert!(!flags.has(StatusFlags::UNDERRUN) && !flags.has(StatusFlags::STOPPED_BY_HOST));
}

#[test]
fn new_is_refused_while_running_and_leaves_the_run_alone() {
    let mut s = Session::<16>::new(16);
    s.start_run(3, &points([0; 8], 3, 1));
    let stops = s.plant.stops;
    let a = s.expect(Command::New { count: 1 }, BadState);
    assert_eq!((a.state, a.buffered), (State::Running, 3));
    assert_eq!(s.plant.stops, stops, "the run goes on");
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.plant.positions[0], 3);
}

#[test]
fn the_first_point_starts_where_the_previous_run_stopped() {
    let mut s = Session::<16>::new(16);
    s.start_run(2, &points([0; 8], 2, 5));
    s.plant.run(&mut s.controller, 1);
    s.expect(Command::Stopped, Ok);
    assert_eq!(s.plant.positions[0], 5);
    s.expect(Command::New { count: 1 }, Ok);
    // An absolute target of 8: 3 steps from where the arm stopped.
    let target = [8, 8, 8, 8, 8, 8, 0, 0];
    s.pending(&[Point::from_motion(1_000, &[5; 8], &target)]);
    s.expect(Command::Runing, Ok);
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.plant.executed.last().map(|g| g.steps[0]), Some(3));
    assert_eq!(s.plant.positions, target);
}

#[test]
fn step_rate_boundary_on_a_long_segment_and_negative_moves() {
    let mut s = Session::<16>::new(16);
    let max = i64::from(s.controller.config().max_step_rate_hz);
    s.expect(Command::New { count: 2 }, Ok);
    // 0.3 s at exactly the limit, backwards; then one step more in the same time.
    let n = (max * 3 / 10) as i32;
    let at_limit = Point::from_motion(300_000, &[0; 8], &[-n, 0, 0, 0, 0, 0, 0, 0]);
    let over = Point::from_motion(
        300_000,
        &at_limit.position,
        &[-2 * n - 1, 0, 0, 0, 0, 0, 0, 0],
    );
    assert_eq!(s.pending(&[at_limit, over]).status, InvalidPoint);
    s.seq = s.seq.wrapping_sub(1);
    assert_eq!(s.pending(&[at_limit]).status, Ok);
}

#[test]
fn points_of_joints_not_in_use_never_move_them_later() {
    let mut s = Session::<16>::new(16);
    s.expect(Command::JointsCount(1), Ok);
    s.expect(Command::New { count: 2 }, Ok);
    // Joint 3's field says 50, then 0: ignored both times, it never moves.
    let p1 = Point::from_motion(1_000, &[0; 8], &[1, 0, 0, 50, 0, 0, 0, 0]);
    let p2 = Point::from_motion(1_000, &p1.position, &[2, 0, 0, 0, 0, 0, 0, 0]);
    s.pending(&[p1, p2]);
    s.expect(Command::Runing, Ok);
    s.plant.run_to_end(&mut s.controller);
    assert!(s.plant.executed.iter().all(|g| g.steps[3] == 0));
    assert_eq!(s.plant.positions, [2, 0, 0, 0, 0, 0, 0, 0]);
}

#[test]
fn value_ranges_are_checked_at_their_bounds() {
    let mut s = Session::<16>::new(16);
    let period = |period_us| Command::UploadPeriod { period_us };
    let usart = |baud_rate| {
        Command::UsartStart(UartInit {
            baud_rate,
            ..UartInit::default()
        })
    };
    let cases: Vec<(Command<'_>, StatusCode)> = vec![
        (period(999), InvalidConfig),
        (period(1_000), Ok),
        (period(1_000_000), Ok),
        (period(1_000_001), InvalidConfig),
        (usart(299), InvalidConfig),
        (usart(300), Ok),
        (usart(4_000_000), Ok),
        (usart(4_000_001), InvalidConfig),
        (Command::JointsCount(0), InvalidConfig),
        (Command::JointsCount(9), InvalidConfig),
        (Command::JointsCount(8), Ok),
        (
            Command::ToggleEnablePins { mask: Some(0x0200) },
            InvalidConfig,
        ),
        (Command::ToggleEnablePins { mask: Some(0x01FF) }, Ok),
        (Command::New { count: 0 }, InvalidConfig),
    ];
    for (cmd, want) in cases {
        s.expect(cmd, want);
    }
    assert_eq!(s.controller.upload_period_us(), 1_000_000);
    let pwm = |psc, arr, ccr1| {
        let mut data = Vec::new();
        for v in [psc, arr, ccr1, 0u32] {
            data.extend_from_slice(&v.to_le_bytes());
        }
        data
    };
    let cases = [
        (pwm(0x1_0000, 10, 5), InvalidConfig),
        (pwm(0, 0x1_0000, 5), InvalidConfig),
        (pwm(0, 10, 11), InvalidConfig),
        (pwm(0xFFFF, 0xFFFF, 0xFFFF), Ok),
    ];
    for (i, (data, want)) in cases.iter().enumerate() {
        let r = s.send_raw(HOST, &raw(200 + i as u8, Tag::PwmStart as u8, data));
        assert_eq!(status_of(&r), *want, "PWM case {i}");
    }
    assert_eq!(
        s.plant.gripper,
        Some(Pwm {
            psc: 0xFFFF,
            arr: 0xFFFF,
            ccr1: 0xFFFF,
            pulse_count: 0
        })
    );
}

#[test]
fn lengths_and_directions_are_checked() {
    let mut s = Session::<16>::new(16);
    s.expect(
        Command::UsartStart(UartInit {
            baud_rate: 9_600,
            mode: 7, // any other value: both directions
            ..UartInit::default()
        }),
        Ok,
    );
    let cases: Vec<(Vec<u8>, StatusCode)> = vec![
        (raw(1, Tag::UsartSend as u8, &[0x55; 255]), Ok),
        (raw(2, Tag::UsartSend as u8, &[0x55; 256]), BadLength),
        (raw(3, Tag::Ack as u8, &[0; 8]), Unsupported),
        (raw(4, Tag::UsartRecv as u8, &[0; 257]), Unsupported),
        // 0x17 is ESTOP_RESET (issue 18), without data; 0x18 SET_ENABLE (issue 23), 3
        // bytes.
        // 0x1f is JOINT_DESC_SET since issue 31 (36 bytes). 0x27-0x33 are being given out to
        // issues 32-34 (hold, homing, diagnostics): 0x4f, below the key's 0x50-0x53, stays unused.
        (raw(5, 0x1F, &[]), BadLength),
        (raw(18, 0x4f, &[]), UnknownTag),
        (raw(14, Tag::SetEnable as u8, &[]), BadLength),
        (raw(13, Tag::EstopReset as u8, &[0]), BadLength),
        (raw(6, 0xFF, &[]), UnknownTag),
        (raw(7, Tag::Pending as u8, &[0; 13 * 116]), BadLength),
        // STATUS takes one request byte (issue 23): bits 0-4 only (bit 2, the STOP_CAUSE
        // report, since issue 31; bit 3, RX_COUNTERS, since issue 30; bit 4, MOTION, since
        // issue 32). Bit 7 stays unknown (this sent 0x08 before RX_COUNTERS took bit 3,
        // 0x10 before MOTION took bit 4).
        (raw(8, Tag::Status as u8, &[0, 0]), BadLength),
        (raw(15, Tag::Status as u8, &[0x80]), InvalidConfig),
        (raw(17, Tag::Status as u8, &[0x04]), Ok),
        (raw(18, Tag::Status as u8, &[0x08]), Ok),
        (raw(19, Tag::Status as u8, &[0x0c]), Ok),
        (raw(16, Tag::Status as u8, &[0x01]), Ok),
        (raw(9, Tag::ToggleEnablePins as u8, &[1]), BadLength),
        (
            raw(10, Tag::UploadPeriod as u8, &[0x10, 0x27, 0]),
            BadLength,
        ),
        (raw(11, Tag::Location as u8, &[0; 34]), BadLength),
        (raw(12, Tag::Location as u8, &[0; 33]), Ok),
    ];
    for (bytes, want) in cases {
        let r = s.send_raw(HOST, &bytes);
        assert_eq!(status_of(&r), want, "tag {:#04x}", bytes[1]);
    }
    assert_eq!(s.plant.serial_sent, vec![vec![0x55; 255]]);
}

#[test]
fn toggle_enable_pins_flips_exactly_the_masked_drivers() {
    let mut s = Session::<16>::new(16);
    s.expect(Command::ToggleEnablePins { mask: Some(0x0101) }, Ok);
    assert_eq!(s.controller.enabled(), 0x00FE);
    s.expect(Command::ToggleEnablePins { mask: Some(0x0101) }, Ok);
    assert_eq!(s.controller.enabled(), 0x01FF, "toggling twice restores");
    s.expect(Command::ToggleEnablePins { mask: Some(0) }, Ok);
    assert_eq!(s.controller.enabled(), 0x01FF, "empty mask: nothing flips");
    s.expect(Command::ToggleEnablePins { mask: None }, Ok);
    assert_eq!(s.controller.enabled(), 0);
    assert!(
        !s.controller
            .status(&s.plant)
            .flags
            .has(StatusFlags::DRIVERS_ENABLED)
    );
    s.expect(Command::ToggleEnablePins { mask: Some(0x0080) }, Ok);
    assert!(
        s.controller
            .status(&s.plant)
            .flags
            .has(StatusFlags::DRIVERS_ENABLED),
        "one driver enabled"
    );
}

#[test]
fn joints_count_is_restored_at_boot() {
    let mut c = controller::<16>(16);
    c.apply_settings(PersistentSettings {
        joints: 3,
        ..PersistentSettings::default()
    });
    assert_eq!(c.joints(), 3);
    let mut c = controller::<16>(16);
    c.apply_settings(PersistentSettings {
        joints: 0,
        ..PersistentSettings::default()
    });
    assert_eq!(c.joints(), 6, "an impossible stored count: the default");
}

#[test]
fn location_setting_ignores_its_state_byte_and_sets_all_positions() {
    let mut s = Session::<16>::new(16);
    let r = s.send_raw(
        HOST,
        &frame(
            1,
            Command::LocationSetting(Location {
                position: [1, 2, 3, 4, 5, 6, 7, 8],
                state: State::Running as u8,
            }),
        ),
    );
    assert_eq!(status_of(&r), Ok);
    assert!(r.location.is_none(), "no state change");
    assert_eq!(s.controller.state(), State::Stopped);
    assert_eq!(s.plant.positions, [1, 2, 3, 4, 5, 6, 7, 8]);
}

// ---- docs/PROTOCOL.md, "Reports (controller to host)" ----

#[test]
fn location_at_once_on_every_state_change_with_the_new_state() {
    let mut s = Session::<16>::new(16);
    let mut seen = Vec::new();
    let mut note = |r: arm_core::Response| seen.push(r.location.map(|l| l.state));
    note(s.send_raw(HOST, &frame(1, Command::New { count: 2 })));
    note(s.send_raw(HOST, &pending(2, &points([0; 8], 1, 1))));
    note(s.send_raw(HOST, &pending(3, &points([1; 8], 1, 1))));
    note(s.send_raw(HOST, &frame(4, Command::Runing)));
    note(s.send_raw(HOST, &frame(5, Command::Runing)));
    let end = s.plant.run_to_end(&mut s.controller);
    let code = |st: State| Some(st as u8);
    assert_eq!(
        seen,
        vec![
            code(State::New),
            code(State::Pending),
            None,
            code(State::Running),
            None
        ]
    );
    assert_eq!(end.map(|l| (l.state, l.position[0])), Some((3, 2)));
    // RETURN: STOPPED -> RUNNING at once.
    let r = s.send_raw(HOST, &frame(6, Command::Return));
    assert_eq!(r.location.map(|l| l.state), code(State::Running));
}

#[test]
fn ack_fields() {
    let mut s = Session::<16>::new(10);
    let r = s.send_raw(HOST, &frame(40, Command::New { count: 5 }));
    let reply = r.reply.unwrap();
    assert_eq!((reply.to, reply.seq), (HOST, 40));
    let a = reply.ack;
    assert_eq!(
        (
            a.acked_tag,
            a.status,
            a.state,
            a.next_seq,
            a.buffered,
            a.free
        ),
        (0x00, Ok, State::New, 41, 0, 10)
    );
    let a = s
        .send_raw(HOST, &pending(41, &points([0; 8], 3, 1)))
        .reply
        .unwrap()
        .ack;
    assert_eq!(
        (a.acked_tag, a.state, a.next_seq, a.buffered, a.free),
        (0x01, State::Pending, 42, 3, 7)
    );
}

#[test]
fn status_report_bytes_at_their_offsets() {
    let mut s = Session::<32>::new(20);
    s.expect(Command::Pin0On, Ok);
    s.expect(
        Command::UsartStart(UartInit {
            baud_rate: 115_200,
            ..UartInit::default()
        }),
        Ok,
    );
    s.expect(Command::UploadStop, Ok);
    s.expect(
        Command::UploadPeriod {
            period_us: 0x0001_2345,
        },
        Ok,
    );
    s.expect(Command::New { count: 0x0107 }, Ok);
    s.pending(&points([0; 8], 3, 1));
    let status = s.controller.status(&s.plant);
    let mut buf = [0u8; 64];
    let n = Report::Status(status).encode(0x33, &mut buf).unwrap();
    assert_eq!(n, 3 + 36);
    let d = &buf[2..2 + 36];
    assert_eq!(&d[0..3], &[1, 0, 0], "version");
    assert_eq!(d[3], 6, "joints");
    assert_eq!(d[4], State::Pending as u8);
    // reports off, drivers on, serial open, PIN0 high, PIN1 low, no underrun, PWM off,
    // not stopped.
    assert_eq!(d[5], 0b0000_1110, "flags");
    assert_eq!(&d[6..8], &32u16.to_le_bytes(), "window");
    assert_eq!(&d[8..10], &3u16.to_le_bytes(), "buffered");
    assert_eq!(&d[10..12], &0x0107u16.to_le_bytes(), "expected");
    assert_eq!(&d[12..14], &3u16.to_le_bytes(), "received");
    assert_eq!(&d[14..16], &0u16.to_le_bytes(), "executed");
    assert_eq!(&d[16..18], &20u16.to_le_bytes(), "capacity");
    // more_flags: bit 3 (per-driver enables reported, issue 23), bit 4 the gripper's
    // ENABLE, bits 8-15 the joints': all enabled at boot; bits 5-7 the stop cause
    // (issue 31): 1, COMPLETE (no run cut short).
    assert_eq!(&d[18..20], &[0b0011_1000, 0xFF], "more_flags");
    assert_eq!(&d[20..24], &0x0001_2345u32.to_le_bytes(), "period");
    let clock = s.controller.config().pwm_timer_clock_hz;
    assert_eq!(&d[24..28], &clock.to_le_bytes());
    let rate = s.controller.config().max_step_rate_hz;
    assert_eq!(&d[28..32], &rate.to_le_bytes());
    // Offset 32: the step rate budget of all joints together (issue 8).
    let budget = arm_core::profile::NUCLEO_H743ZI2.step_budget_hz;
    assert_eq!(&d[32..36], &budget.to_le_bytes(), "step budget");
}

#[test]
fn usart_recv_is_always_257_data_bytes() {
    let mut buf = [0u8; 300];
    let n = Report::UsartRecv(b"ok\r\n").encode(0x2b, &mut buf).unwrap();
    assert_eq!(n, 3 + 257);
    assert_eq!(buf[2], 4, "len");
    assert_eq!(&buf[3..7], b"ok\r\n");
    assert!(buf[7..2 + 257].iter().all(|b| *b == 0), "rest zero");
    let n = Report::UsartRecv(&[0xAA; 255]).encode(0, &mut buf).unwrap();
    assert_eq!((n, buf[2]), (260, 255));
}

#[test]
fn a_resent_new_does_not_drop_the_upload_it_started() {
    let mut s = Session::<16>::new(16);
    let new = frame(20, Command::New { count: 4 });
    s.send_raw(HOST, &new);
    assert_eq!(
        status_of(&s.send_raw(HOST, &pending(21, &points([0; 8], 2, 1)))),
        Ok
    );
    // NEW's ACK was lost; the host resends it: a duplicate, the 2 points stay.
    let ack = s.send_raw(HOST, &new).reply.unwrap().ack;
    assert_eq!((ack.status, ack.buffered, ack.next_seq), (Ok, 2, 22));
    assert_eq!(s.controller.state(), State::Pending);
}

/// Issue 21 F9: a BAD_CRC ACK to a stranger carried the real state, the uploader's next
/// seq and the buffer counts, though a stranger is to learn nothing (section 8). The
/// owner's own BAD_CRC still carries them (it resends and may need next_seq).
#[test]
fn a_bad_crc_tells_a_stranger_nothing_and_the_owner_everything() {
    let mut s = Session::<16>::new(16);
    s.expect(Command::New { count: 4 }, Ok);
    assert_eq!(s.pending(&points([0; 8], 2, 1)).status, Ok);
    let mut bad = frame(9, Command::Status);
    *bad.last_mut().unwrap() ^= 1;
    let stranger = s.send_raw(OTHER, &bad).reply.expect("an ACK").ack;
    assert_eq!(stranger.status, BadCrc);
    assert_eq!(
        (
            stranger.state,
            stranger.next_seq,
            stranger.buffered,
            stranger.free
        ),
        (State::New, 0, 0, 0),
        "nothing about the arm: the NOT_OWNER zeros"
    );
    let owner = s.send_raw(HOST, &bad).reply.expect("an ACK").ack;
    assert_eq!(owner.status, BadCrc);
    assert_eq!((owner.state, owner.buffered), (State::Pending, 2));
}
