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
