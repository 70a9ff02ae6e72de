//! Issue 23's wire-side tools: explicit per-joint enable (SET_ENABLE, STATUS `more_flags`
//! bits 3-4 and 8-15), read-only STATUS for any host and RELEASE, limits on the controller.
//! The frames are built from raw bytes (tag and layout as docs/PROTOCOL.md gives them), so
//! that each test also pins the wire format.

mod common;

use common::*;
use protocol::{Command, MoreFlags, Report, State, StatusCode, Tag};

use StatusCode::*;

const SET_ENABLE: u8 = 0x18;

/// SET_ENABLE's data: the mask (u16 little-endian: bits 0-7 joints, 8 gripper), then the
/// action (0 disable, 1 enable).
fn set_enable(mask: u16, enable: u8) -> Vec<u8> {
    let [lo, hi] = mask.to_le_bytes();
    vec![lo, hi, enable]
}

/// Sends `tag` with `data` and the session's next seq from its host; returns the status.
fn send_raw_cmd(s: &mut Session<64>, tag: u8, data: &[u8]) -> StatusCode {
    s.seq = s.seq.wrapping_add(1);
    let bytes = raw(s.seq, tag, data);
    let from = s.from;
    s.send_raw(from, &bytes).reply.expect("an ACK").ack.status
}

fn status(s: &mut Session<64>) -> protocol::StatusReport {
    s.seq = s.seq.wrapping_add(1);
    let bytes = frame(s.seq, Command::Status);
    let from = s.from;
    s.send_raw(from, &bytes).status.expect("a STATUS report").1
}

#[test]
fn set_enable_sets_the_masked_drivers_explicitly_never_toggles() {
    let mut s = Session::<64>::new(64);
    // Boot: every driver enabled (holding).
    assert_eq!(s.controller.enabled(), 0x1FF);
    // Disable joints 0 and 1: twice, and they stay disabled (TOGGLE would re-enable).
    assert_eq!(send_raw_cmd(&mut s, SET_ENABLE, &set_enable(0x003, 0)), Ok);
    assert_eq!(s.controller.enabled(), 0x1FC);
    assert_eq!(s.plant.enabled.last(), Some(&0x1FC));
    assert_eq!(send_raw_cmd(&mut s, SET_ENABLE, &set_enable(0x003, 0)), Ok);
    assert_eq!(s.controller.enabled(), 0x1FC);
    // Enable joint 0 and the gripper (already on): only joint 0 changes.
    assert_eq!(send_raw_cmd(&mut s, SET_ENABLE, &set_enable(0x101, 1)), Ok);
    assert_eq!(s.controller.enabled(), 0x1FD);
    assert_eq!(send_raw_cmd(&mut s, SET_ENABLE, &set_enable(0x101, 1)), Ok);
    assert_eq!(s.controller.enabled(), 0x1FD);
    // Disable the gripper alone.
    assert_eq!(send_raw_cmd(&mut s, SET_ENABLE, &set_enable(0x100, 0)), Ok);
    assert_eq!(s.controller.enabled(), 0x0FD);
}

#[test]
fn set_enable_refuses_bad_input_with_a_status_and_changes_nothing() {
    let mut s = Session::<64>::new(64);
    // A bit above the gripper's, an action other than 0 or 1, a wrong length.
    assert_eq!(
        send_raw_cmd(&mut s, SET_ENABLE, &set_enable(0x200, 0)),
        InvalidConfig
    );
    assert_eq!(
        send_raw_cmd(&mut s, SET_ENABLE, &set_enable(0x001, 2)),
        InvalidConfig
    );
    assert_eq!(send_raw_cmd(&mut s, SET_ENABLE, &[0x01, 0x00]), BadLength);
    assert_eq!(send_raw_cmd(&mut s, SET_ENABLE, &[]), BadLength);
    assert_eq!(
        send_raw_cmd(&mut s, SET_ENABLE, &[0x01, 0x00, 0x00, 0x00]),
        BadLength
    );
    assert_eq!(s.controller.enabled(), 0x1FF);
    // Only while STOPPED, as TOGGLE_ENABLE_PINS: a limp joint mid-run loses its steps.
    s.start_endless_run();
    assert_eq!(
        send_raw_cmd(&mut s, SET_ENABLE, &set_enable(0x001, 0)),
        BadState
    );
    assert_eq!(s.controller.enabled(), 0x1FF);
    s.expect(Command::New { count: 1 }, BadState);
}

#[test]
fn status_reports_each_drivers_enable_in_more_flags() {
    let mut s = Session::<64>::new(64);
    let st = status(&mut s);
    // Bit 3: this controller reports per-driver enables; bits 8-15 joints 0-7, bit 4 the
    // gripper.
    assert!(st.more_flags.has(MoreFlags::ENABLES_REPORTED));
    assert_eq!(st.more_flags.0 >> 8, 0xFF);
    assert!(st.more_flags.has(MoreFlags::GRIPPER_ENABLED));
    assert_eq!(st.drivers_enabled(), Some(0x1FF));
    assert_eq!(send_raw_cmd(&mut s, SET_ENABLE, &set_enable(0x105, 0)), Ok);
    let st = status(&mut s);
    assert_eq!(st.more_flags.0 >> 8, 0xFA);
    assert!(!st.more_flags.has(MoreFlags::GRIPPER_ENABLED));
    assert_eq!(st.drivers_enabled(), Some(0x0FA));
    // The old summary bit still says "any driver enabled".
    assert!(st.flags.has(protocol::StatusFlags::DRIVERS_ENABLED));
    // The other bits keep their meaning and stay clear.
    assert!(!st.more_flags.has(MoreFlags::UPLOAD_DROPPED));
    assert!(!st.more_flags.has(MoreFlags::ESTOP_OPEN));
    // TOGGLE_ENABLE_PINS (old hosts) is reported the same way.
    s.expect(Command::ToggleEnablePins { mask: Some(0x0FF) }, Ok);
    assert_eq!(status(&mut s).drivers_enabled(), Some(0x005));
    // A STATUS from an older controller (bit 3 clear) tells nothing per driver.
    let old = protocol::StatusReport {
        more_flags: MoreFlags(0xFF00),
        ..st
    };
    assert_eq!(old.drivers_enabled(), None);
    let _ = (Report::Status(st), Tag::Status, State::Stopped);
}

const RELEASE: u8 = 0x19;

/// The owner's clock moves on by `us` (its silence grows).
fn wait(s: &mut Session<64>, us: u64) {
    s.now_us += us;
}

#[test]
fn a_stranger_reads_status_without_taking_the_controller() {
    let mut s = Session::<64>::new(64);
    s.expect(Command::Status, Ok);
    s.start_endless_run();
    let r = s.send_raw(OTHER, &frame(7, Command::Status));
    let ack = r.reply.expect("an ACK").ack;
    assert_eq!(ack.status, Ok, "STATUS is readable by any host (issue 23)");
    assert_eq!(ack.state, State::Running);
    // Nothing that helps forge a frame: no next seq, no buffer counts in the ACK.
    assert_eq!((ack.next_seq, ack.buffered, ack.free), (0, 0, 0));
    let (to, report) = r.status.expect("a STATUS report for the stranger");
    assert_eq!(to, OTHER);
    assert_eq!(report.state, State::Running);
    // The owner stays, and the stranger's other commands are still refused.
    assert_eq!(s.controller.owner().map(|o| o.ip), Some(HOST.ip));
    let r = s.send_raw(OTHER, &frame(8, Command::Pin0On));
    assert_eq!(r.reply.unwrap().ack.status, NotOwner);
    // The stranger's STATUS is not remembered: asking again with the same bytes is
    // answered again.
    let r = s.send_raw(OTHER, &frame(7, Command::Status));
    assert!(r.status.is_some());
    // A stranger's STATUS refreshes nothing of the owner's: after 5 s of the owner's
    // silence (the arm stopped), the stranger can take over as before.
    s.expect(Command::Stopped, Ok);
    wait(&mut s, arm_core::config::OWNER_TIMEOUT_US);
    let r = s.send_raw(OTHER, &frame(9, Command::Pin0On));
    assert_eq!(r.reply.unwrap().ack.status, Ok);
    assert_eq!(s.controller.owner().map(|o| o.ip), Some(OTHER.ip));
}

#[test]
fn release_hands_the_controller_over_at_once_and_a_resend_does_not_take_it_back() {
    let mut s = Session::<64>::new(64);
    s.expect(Command::Status, Ok);
    let r = s.send_raw(OTHER, &frame(1, Command::New { count: 1 }));
    assert_eq!(r.reply.unwrap().ack.status, NotOwner);
    // RELEASE (0x19, no data) from the owner.
    let release = raw(40, RELEASE, &[]);
    let r = s.send_raw(HOST, &release);
    assert_eq!(r.reply.unwrap().ack.status, Ok);
    assert_eq!(s.controller.owner(), None);
    // Its ACK was lost: the same bytes again are OK and take nothing.
    let r = s.send_raw(HOST, &release);
    assert_eq!(r.reply.unwrap().ack.status, Ok);
    assert_eq!(s.controller.owner(), None);
    // A malformed RELEASE from a host that does not own it: BAD_LENGTH, nothing taken
    // (found by the controller fuzz target).
    let r = s.send_raw(OTHER, &raw(42, RELEASE, &[1, 2, 3]));
    assert_eq!(r.reply.unwrap().ack.status, BadLength);
    assert_eq!(s.controller.owner(), None);
    // Another host takes the controller at once, no 5 s wait.
    let r = s.send_raw(OTHER, &frame(2, Command::New { count: 1 }));
    assert_eq!(r.reply.unwrap().ack.status, Ok);
    assert_eq!(s.controller.owner().map(|o| o.ip), Some(OTHER.ip));
    // A late copy of the old owner's RELEASE: NOT_OWNER, the new owner keeps it.
    let r = s.send_raw(HOST, &release);
    assert_eq!(r.reply.unwrap().ack.status, NotOwner);
    assert_eq!(s.controller.owner().map(|o| o.ip), Some(OTHER.ip));
    // Another's RELEASE never releases.
    let r = s.send_raw(HOST, &raw(41, RELEASE, &[]));
    assert_eq!(r.reply.unwrap().ack.status, NotOwner);
    assert_eq!(s.controller.owner().map(|o| o.ip), Some(OTHER.ip));
}

#[test]
fn release_only_while_stopped_and_without_data() {
    let mut s = Session::<64>::new(64);
    s.start_endless_run();
    assert_eq!(send_raw_cmd(&mut s, RELEASE, &[]), BadState);
    assert_eq!(s.controller.owner().map(|o| o.ip), Some(HOST.ip));
    s.expect(Command::Stopped, Ok);
    assert_eq!(send_raw_cmd(&mut s, RELEASE, &[0]), BadLength);
    assert_eq!(s.controller.owner().map(|o| o.ip), Some(HOST.ip));
    assert_eq!(send_raw_cmd(&mut s, RELEASE, &[]), Ok);
    assert_eq!(s.controller.owner(), None);
    // No LOCATION goes anywhere once released.
    assert_eq!(
        s.controller.report_settings().location_to,
        [None; arm_core::reports::LOCATION_LISTENERS]
    );
}

fn status_with(seq: u8, ask: protocol::StatusAsk) -> Vec<u8> {
    frame(seq, Command::StatusWith(ask))
}

#[test]
fn status_asks_for_a_location_and_a_look_only_status_never_takes_a_free_controller() {
    use protocol::StatusAsk;
    let mut s = Session::<64>::new(64);
    s.plant.positions = [11, -22, 33, 0, 0, 0, 0, 0];
    let look = StatusAsk {
        location: true,
        look_only: true,
        stop_cause: false,
        counters: false,
        diag: false,
        motion: false,
    };
    // Nobody owns it: a look-only STATUS is answered and takes nothing.
    let r = s.send_raw(OTHER, &status_with(5, look));
    assert_eq!(r.reply.unwrap().ack.status, Ok);
    assert_eq!(s.controller.owner(), None);
    assert_eq!(
        r.answer_seq,
        Some(5),
        "the asker's own seq, not the report counter"
    );
    let (to, location) = r.asked_location.expect("the LOCATION asked for");
    assert_eq!(to, OTHER);
    assert_eq!(location.position[..3], [11, -22, 33]);
    // The same from the owner-to-be without look_only takes it, and gets its reports
    // with the report counter (no answer_seq).
    let ask = StatusAsk {
        location: true,
        look_only: false,
        stop_cause: false,
        motion: false,
        counters: false,
        diag: false,
    };
    let r = s.send_raw(HOST, &status_with(6, ask));
    assert_eq!(s.controller.owner().map(|o| o.ip), Some(HOST.ip));
    assert_eq!(r.answer_seq, None);
    assert!(r.status.is_some() && r.asked_location.is_some());
    // The owner's look_only changes nothing for it: it is the owner.
    let r = s.send_raw(HOST, &status_with(7, look));
    assert_eq!(r.answer_seq, None);
    assert_eq!(r.reply.unwrap().ack.status, Ok);
    // A request byte with other bits: INVALID_CONFIG (to the owner, as any command).
    // Bit 2 asks for the STOP_CAUSE report since issue 31, bit 3 for RX_COUNTERS since
    // issue 30 and bit 4 for MOTION since issue 32: bit 7 stays unknown (this sent 0x08,
    // then 0x10, before).
    let r = s.send_raw(HOST, &raw(8, Tag::Status as u8, &[0x80]));
    assert_eq!(r.reply.unwrap().ack.status, InvalidConfig);
}

#[test]
fn read_only_answers_are_bounded_like_discover() {
    let mut s = Session::<64>::new(64);
    s.expect(Command::Status, Ok);
    let burst = arm_core::DISCOVER_BURST as usize;
    let answered = (0..burst + 5)
        .filter(|i| {
            let r = s.send_raw(OTHER, &frame(*i as u8, Command::Status));
            r.reply.is_some()
        })
        .count();
    assert_eq!(answered, burst, "a burst, then nothing");
    // A second later: DISCOVER_REPLIES_PER_S more.
    s.now_us += 1_000_000;
    let again = (0..20)
        .filter(|i| {
            s.send_raw(OTHER, &frame(*i, Command::Status))
                .reply
                .is_some()
        })
        .count();
    assert_eq!(again, arm_core::DISCOVER_REPLIES_PER_S as usize);
    // The owner is never limited.
    for _ in 0..30 {
        s.expect(Command::Status, Ok);
    }
}

#[test]
fn a_read_only_answer_carries_the_askers_seq_and_leaves_the_report_counter_alone() {
    use arm_core::{Answer, AnswerReport, Outgoing, ReportEncoder};
    let mut enc = ReportEncoder::new();
    let routes = Session::<64>::new(64).controller.report_settings();
    let mut buf = [0u8; 64];
    let out = Outgoing::Answer(Answer {
        to: OTHER,
        seq: Some(0x77),
        report: AnswerReport::Status(protocol::StatusReport::default()),
    });
    let (to, n) = enc.encode(&out, &routes, 0, &mut buf).unwrap();
    assert_eq!(to.as_slice(), &[OTHER]);
    assert_eq!(buf[0], 0x77);
    assert!(matches!(
        Report::decode(&buf[..n]).unwrap().body,
        Report::Status(_)
    ));
    assert_eq!(enc.next_seq(), 0, "the counter did not move");
    let out = Outgoing::Answer(Answer {
        to: HOST,
        seq: None,
        report: AnswerReport::Location(protocol::Location::default()),
    });
    enc.encode(&out, &routes, 0, &mut buf).unwrap();
    assert_eq!((buf[0], enc.next_seq()), (0, 1));
}

const LIMITS_SET: u8 = 0x1a;
const LIMITS_GET: u8 = 0x1b;

/// LIMITS_SET's data: joint u8, 3 reserved bytes, min i32, max i32, max_rate_hz u32 (all
/// little-endian).
fn limits_set(joint: u8, min: i32, max: i32, rate: u32) -> Vec<u8> {
    let mut d = vec![joint, 0, 0, 0];
    d.extend_from_slice(&min.to_le_bytes());
    d.extend_from_slice(&max.to_le_bytes());
    d.extend_from_slice(&rate.to_le_bytes());
    d
}

/// A point of 10 ms that moves every joint in use to `to` (the others stay).
fn point_to(from: [i32; 8], to: [i32; 8]) -> protocol::Point {
    protocol::Point::from_motion(10_000, &from, &to)
}

#[test]
fn limits_are_set_stored_and_enforced_at_pending() {
    let mut s = Session::<64>::new(64);
    // Joint 1: -100..100 steps, 2000 steps/s at most.
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(
        HOST,
        &raw(s.seq, LIMITS_SET, &limits_set(1, -100, 100, 2_000)),
    );
    assert_eq!(r.reply.unwrap().ack.status, Ok);
    assert!(
        matches!(r.deferred, Some(arm_core::Deferred::SaveSettings(_))),
        "kept across power cycles, as JOINTS_COUNT"
    );
    // A refused PENDING leaves its seq a gap (section 7): each try starts with a NEW.
    let try_point = |s: &mut Session<64>, p: protocol::Point| {
        s.expect(Command::New { count: 3 }, Ok);
        let status = s.pending(&[p]).status;
        (status, s.controller.buffered())
    };
    // 150 is above joint 1's max: the frame is refused, nothing taken.
    let over = point_to([0; 8], [0, 150, 0, 0, 0, 0, 0, 0]);
    assert_eq!(try_point(&mut s, over), (InvalidPoint, 0));
    // -101 is below the min.
    let under = point_to([0; 8], [0, -101, 0, 0, 0, 0, 0, 0]);
    assert_eq!(try_point(&mut s, under), (InvalidPoint, 0));
    // 30 steps in 10 ms is 3000 steps/s, over the joint's 2000 (the board takes 200k).
    let fast = point_to([0; 8], [0, 30, 0, 0, 0, 0, 0, 0]);
    assert_eq!(try_point(&mut s, fast), (InvalidPoint, 0));
    // Within everything: taken; the other joints are not limited.
    let fine = point_to([0; 8], [1_000, 20, 0, 0, 0, 0, 0, 0]);
    assert_eq!(try_point(&mut s, fine), (Ok, 1));
    // Only while STOPPED.
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(HOST, &raw(s.seq, LIMITS_SET, &limits_set(1, -5, 5, 0)));
    assert_eq!(r.reply.unwrap().ack.status, BadState);
}

#[test]
fn limits_refuse_bad_input_and_apply_to_return_and_location_setting() {
    let mut s = Session::<64>::new(64);
    let set = |s: &mut Session<64>, data: &[u8]| send_raw_cmd(s, LIMITS_SET, data);
    // Joint 8 does not exist; min above max; wrong lengths.
    assert_eq!(set(&mut s, &limits_set(8, 0, 1, 0)), InvalidConfig);
    assert_eq!(set(&mut s, &limits_set(0, 10, -10, 0)), InvalidConfig);
    assert_eq!(set(&mut s, &limits_set(0, 0, 1, 0)[..15]), BadLength);
    // LIMITS_GET takes one request byte since issue 31 (0x01: with the accelerations);
    // another value is INVALID_CONFIG (it was BAD_LENGTH), two bytes BAD_LENGTH.
    assert_eq!(send_raw_cmd(&mut s, LIMITS_GET, &[0]), InvalidConfig);
    assert_eq!(send_raw_cmd(&mut s, LIMITS_GET, &[1, 0]), BadLength);
    assert_eq!(send_raw_cmd(&mut s, LIMITS_GET, &[1]), Ok);
    // Joint 0 may not reach 0: RETURN is refused before anything moves.
    assert_eq!(set(&mut s, &limits_set(0, 100, 1_000, 0)), Ok);
    s.set_location([500, 0, 0, 0, 0, 0, 0, 0]);
    s.expect(Command::Return, InvalidPoint);
    assert_eq!(s.controller.state(), State::Stopped);
    // LOCATION_SETTING outside a joint's range: refused (widen the limits first).
    let outside = protocol::Location {
        position: [50, 0, 0, 0, 0, 0, 0, 0],
        state: 0,
    };
    s.expect(Command::LocationSetting(outside), InvalidPoint);
    assert_eq!(s.plant.positions[0], 500);
    // The whole range again (i32::MIN..=i32::MAX, no rate of its own): RETURN works.
    assert_eq!(set(&mut s, &limits_set(0, i32::MIN, i32::MAX, 0)), Ok);
    s.expect(Command::Return, Ok);
}

#[test]
fn limits_get_reports_every_joint_and_names_the_last_refusal() {
    use protocol::{JointLimits, LimitsSet, RefusalReason};
    let mut s = Session::<64>::new(64);
    let limits = JointLimits {
        min: -100,
        max: 100,
        max_rate_hz: 2_000,
    };
    s.expect(Command::LimitsSet(LimitsSet { joint: 2, limits }), Ok);
    s.expect(Command::New { count: 2 }, Ok);
    let ok = point_to([0; 8], [0, 0, 10, 0, 0, 0, 0, 0]);
    let over = point_to([0, 0, 10, 0, 0, 0, 0, 0], [0, 0, 120, 0, 0, 0, 0, 0]);
    assert_eq!(s.pending(&[ok, over]).status, InvalidPoint);
    let refused_seq = s.seq;
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(HOST, &frame(s.seq, Command::LimitsGet));
    assert_eq!(r.reply.unwrap().ack.status, Ok);
    let (to, report) = r.limits.expect("a LIMITS report");
    assert_eq!(to, HOST);
    assert_eq!(report.joints[2], limits);
    assert_eq!(report.joints[0], JointLimits::NONE);
    let refusal = report.last_refusal;
    assert_eq!(
        (refusal.seq, refusal.tag, refusal.point, refusal.joint),
        (refused_seq, Tag::Pending as u8, 1, 2),
        "the second point of that PENDING, joint 2"
    );
    assert_eq!(
        (refusal.reason, refusal.value, refusal.limit),
        (RefusalReason::AboveMax, 120, 100)
    );
    // A rate: 30 steps in 10 ms = 3000 steps/s against the joint's 2000.
    s.expect(Command::New { count: 1 }, Ok);
    let fast = point_to([0; 8], [0, 0, 30, 0, 0, 0, 0, 0]);
    assert_eq!(s.pending(&[fast]).status, InvalidPoint);
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(HOST, &frame(s.seq, Command::LimitsGet));
    let refusal = r.limits.unwrap().1.last_refusal;
    assert_eq!(
        (refusal.joint, refusal.reason, refusal.value, refusal.limit),
        (2, RefusalReason::JointRate, 3_000, 2_000)
    );
    // The limits are kept in the settings the board stores.
    assert_eq!(s.controller.settings().limits[2], limits);
}

#[test]
fn stored_limits_apply_at_boot_and_an_impossible_range_is_none() {
    use protocol::JointLimits;
    let mut s = Session::<64>::new(64);
    let mut stored = arm_core::hw::PersistentSettings::DEFAULT;
    stored.limits[0] = JointLimits {
        min: 0,
        max: 50,
        max_rate_hz: 0,
    };
    stored.limits[1] = JointLimits {
        min: 10,
        max: -10,
        max_rate_hz: 0,
    };
    s.controller.apply_settings(stored);
    assert_eq!(s.controller.settings().limits[0], stored.limits[0]);
    assert_eq!(s.controller.settings().limits[1], JointLimits::NONE);
    s.expect(Command::New { count: 1 }, Ok);
    let over = point_to([0; 8], [60, 0, 0, 0, 0, 0, 0, 0]);
    assert_eq!(s.pending(&[over]).status, InvalidPoint);
}

#[test]
fn return_moves_no_joint_faster_than_its_own_limit() {
    use protocol::{JointLimits, LimitsSet};
    let mut s = Session::<64>::new(64);
    let slow = JointLimits {
        max_rate_hz: 500,
        ..JointLimits::NONE
    };
    s.expect(
        Command::LimitsSet(LimitsSet {
            joint: 0,
            limits: slow,
        }),
        Ok,
    );
    s.set_location([2_000, 2_000, 0, 0, 0, 0, 0, 0]);
    s.expect(Command::Return, Ok);
    s.controller.begin_return(None, &mut s.plant);
    s.plant.run_to_end(&mut s.controller);
    assert_eq!(s.plant.positions[..2], [0, 0]);
    for seg in &s.plant.executed {
        let rate =
            |steps: i32| u64::from(steps.unsigned_abs()) * 1_000_000 / u64::from(seg.duration_us);
        assert!(
            rate(seg.steps[0]) <= 500,
            "joint 0 at {} steps/s",
            rate(seg.steps[0])
        );
    }
}

#[test]
fn with_a_key_a_plain_status_is_still_refused_and_a_key_holder_reads_read_only() {
    use protocol::auth::{AuthKey, KEY_LEN};
    const KEY: AuthKey = AuthKey([0x5a; KEY_LEN]);
    let mut s = Session::<64>::new(64);
    s.expect(Command::SetKey(Some(KEY)), Ok);
    s.hello(KEY);
    s.expect(Command::Status, Ok);
    // A host without the key: AUTH_REQUIRED, as before issue 23 (section 13 unchanged).
    let r = s.send_raw(OTHER, &frame(3, Command::Status));
    assert_eq!(r.reply.unwrap().ack.status, AuthRequired);
    assert!(r.status.is_none());
    let r = s.send_raw(OTHER, &raw(4, RELEASE, &[]));
    assert_eq!(r.reply.unwrap().ack.status, AuthRequired);
    // Another key holder (its own session, another address): read-only.
    let mut other = Session::<64>::new(64);
    std::mem::swap(&mut other.controller, &mut s.controller);
    other.now_us = s.now_us;
    other.from = OTHER;
    other.seq = 50;
    other.hello(KEY);
    let ack = other.send(Command::Status);
    assert_eq!((ack.status, ack.next_seq, ack.free), (Ok, 0, 0));
    assert_eq!(other.controller.owner().map(|o| o.ip), Some(HOST.ip));
    assert_eq!(other.send(Command::Pin0On).status, NotOwner);
}
