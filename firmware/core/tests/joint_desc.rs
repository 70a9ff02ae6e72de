//! Issue 31: the controller keeps each joint's description (JOINT_DESC_SET: name, units,
//! scale) with its limits, under the rule of the commands that write flash (STOPPED only,
//! saved before the ACK), and answers JOINT_DESC_GET with it in any state.

mod common;

use arm_core::Deferred;
use common::*;
use protocol::{Command, JointDesc, JointDescSet, JointUnit, StatusCode, Tag};

fn shoulder() -> JointDescSet {
    JointDescSet {
        joint: 1,
        desc: JointDesc::new("shoulder", JointUnit::Degrees, -5, 2546.479089470325).unwrap(),
    }
}

fn get(s: &mut Session<64>, joint: u8) -> JointDescSet {
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(HOST, &frame(s.seq, Command::JointDescGet { joint }));
    assert_eq!(r.reply.map(|r| r.ack.status), Some(StatusCode::Ok));
    r.joint_desc.expect("a JOINT_DESC report").1
}

#[test]
fn a_description_is_saved_applied_at_boot_and_read_in_any_state() {
    let mut s = Session::<64>::new(64);
    assert_eq!(get(&mut s, 1).desc, JointDesc::NONE, "none at boot");
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(HOST, &frame(s.seq, Command::JointDescSet(shoulder())));
    assert_eq!(r.reply.map(|r| r.ack.status), Some(StatusCode::Ok));
    let Some(Deferred::SaveSettings(saved)) = r.deferred else {
        panic!("saved: {:?}", r.deferred)
    };
    assert_eq!(saved.desc[1], shoulder().desc);
    assert_eq!(saved.desc[0], JointDesc::NONE, "the other joints unchanged");
    // Kept: applied at the next boot and read back by any asker.
    let mut booted = Session::<64>::new(64);
    booted.controller.apply_settings(saved);
    assert_eq!(get(&mut booted, 1), shoulder());
    // Read during an upload too; not set during one (it writes flash: STOPPED only).
    booted.expect(Command::New { count: 2 }, StatusCode::Ok);
    assert_eq!(get(&mut booted, 1), shoulder());
    assert_eq!(
        booted.send(Command::JointDescSet(shoulder())).status,
        StatusCode::BadState
    );
}

#[test]
fn bad_descriptions_are_refused_and_change_nothing() {
    let mut s = Session::<64>::new(64);
    let mut data = vec![8u8, 0, 0, 0];
    data.extend_from_slice(b"elbow\0\0\0\0\0\0\0\0\0\0\0");
    data.extend_from_slice(&[1, 0, 0, 0, 0, 0, 0, 0]);
    data.extend_from_slice(&1000.0f64.to_le_bytes());
    for (what, bytes) in [
        ("joint 8", data.clone()),
        ("unit 9", {
            let mut d = data.clone();
            d[0] = 2;
            d[20] = 9;
            d
        }),
        ("a NaN scale", {
            let mut d = data.clone();
            d[0] = 2;
            d[28..36].copy_from_slice(&f64::NAN.to_le_bytes());
            d
        }),
    ] {
        s.seq = s.seq.wrapping_add(1);
        let r = s.send_raw(HOST, &raw(s.seq, Tag::JointDescSet as u8, &bytes));
        assert_eq!(
            r.reply.map(|r| r.ack.status),
            Some(StatusCode::InvalidConfig),
            "{what}"
        );
        assert_eq!(r.deferred, None, "{what}: nothing saved");
    }
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(HOST, &raw(s.seq, Tag::JointDescSet as u8, &data[..35]));
    assert_eq!(r.reply.map(|r| r.ack.status), Some(StatusCode::BadLength));
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(HOST, &raw(s.seq, Tag::JointDescGet as u8, &[8]));
    assert_eq!(
        r.reply.map(|r| r.ack.status),
        Some(StatusCode::InvalidConfig)
    );
    assert_eq!(r.joint_desc, None);
}

/// Any host may read the description, and reading it never takes the controller: from a
/// host that does not own it (another does, or none does) JOINT_DESC_GET is answered
/// read-only with the request's seq, as a look-only STATUS.
#[test]
fn any_host_reads_the_description_without_taking_the_controller() {
    let mut s = Session::<64>::new(64);
    s.seq = s.seq.wrapping_add(1);
    let r = s.send_raw(HOST, &frame(s.seq, Command::JointDescSet(shoulder())));
    let Some(Deferred::SaveSettings(saved)) = r.deferred else {
        panic!("saved: {:?}", r.deferred)
    };
    let mut fresh = Session::<64>::new(64);
    fresh.controller.apply_settings(saved);
    // No owner yet: a reader gets the description and the controller stays free.
    let r = fresh.send_raw(OTHER, &frame(0x40, Command::JointDescGet { joint: 1 }));
    assert_eq!(r.reply.map(|r| r.ack.status), Some(StatusCode::Ok));
    assert_eq!(r.joint_desc.map(|d| d.1), Some(shoulder()));
    assert_eq!(r.answer_seq, Some(0x40));
    assert_eq!(
        fresh.controller.owner(),
        None,
        "reading took the controller"
    );
    // With an owner: still answered to the other host; the owner keeps it.
    fresh.expect(Command::Status, StatusCode::Ok);
    let owner = fresh.controller.owner();
    assert!(owner.is_some());
    let r = fresh.send_raw(OTHER, &frame(0x41, Command::JointDescGet { joint: 1 }));
    assert_eq!(r.reply.map(|r| r.ack.status), Some(StatusCode::Ok));
    assert_eq!(r.joint_desc.map(|d| d.1), Some(shoulder()));
    assert_eq!(fresh.controller.owner(), owner);
}
