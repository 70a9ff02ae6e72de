//! Issue 23's frames (after the shared golden file): SET_ENABLE (0x18) and STATUS
//! `more_flags` bits 3, 4 and 8-15 (docs/PROTOCOL.md section 4, SET_ENABLE; section 5,
//! "Each driver's ENABLE").

use protocol::{
    Command, DecodeErrorKind, Field, MoreFlags, Report, State, StatusFlags, StatusReport, Tag,
};

fn encode(cmd: Command<'_>, seq: u8) -> Vec<u8> {
    let mut buf = [0u8; protocol::MAX_DATAGRAM];
    let n = cmd.encode(seq, &mut buf).unwrap();
    buf[..n].to_vec()
}

fn with_crc(mut bytes: Vec<u8>) -> Vec<u8> {
    bytes.push(protocol::crc8(&bytes));
    bytes
}

#[test]
fn set_enable_is_tag_0x18_with_a_little_endian_mask_and_an_action() {
    assert_eq!(Tag::SetEnable as u8, 0x18);
    assert_eq!(Tag::SetEnable.name(), "SET_ENABLE");
    let cmd = Command::SetEnable {
        mask: 0x0103,
        enable: false,
    };
    let bytes = encode(cmd, 0x1b);
    assert_eq!(&bytes[..5], &[0x1b, 0x18, 0x03, 0x01, 0x00]);
    assert_eq!(Command::decode(&bytes).unwrap().body, cmd);
    let on = encode(
        Command::SetEnable {
            mask: 0x01ff,
            enable: true,
        },
        0x1c,
    );
    assert_eq!(on, [0x1c, 0x18, 0xff, 0x01, 0x01, 0x4a]);
}

#[test]
fn set_enable_refuses_what_it_cannot_mean() {
    let kind = |data: &[u8]| {
        Command::decode(&with_crc([&[1, 0x18][..], data].concat()))
            .unwrap_err()
            .kind
    };
    assert_eq!(
        kind(&[0x00, 0x02, 1]),
        DecodeErrorKind::OutOfRange(Field::EnableMask)
    );
    assert_eq!(
        kind(&[0x01, 0x00, 2]),
        DecodeErrorKind::OutOfRange(Field::EnableAction)
    );
    assert!(matches!(
        kind(&[0x01, 0x00]),
        DecodeErrorKind::BadLength { .. }
    ));
    assert!(matches!(kind(&[]), DecodeErrorKind::BadLength { .. }));
}

#[test]
fn status_more_flags_carry_each_drivers_enable_old_hosts_see_36_bytes() {
    let status = StatusReport {
        version: protocol::VERSION,
        joints: 6,
        state: State::Stopped,
        flags: StatusFlags(StatusFlags::DRIVERS_ENABLED),
        more_flags: MoreFlags(MoreFlags::of_enabled(0x105)),
        ..StatusReport::default()
    };
    let mut buf = [0u8; 64];
    let n = Report::Status(status).encode(7, &mut buf).unwrap();
    // Still 36 data bytes: every decoder of STATUS reads exactly that many.
    assert_eq!(n, 3 + 36);
    // Offset 18, little-endian: bit 3 (reported), bit 4 (gripper), bits 8-15 (joints).
    assert_eq!(&buf[2 + 18..2 + 20], &[0b0001_1000, 0b0000_0101]);
    let back = match Report::decode(&buf[..n]).unwrap().body {
        Report::Status(s) => s,
        other => panic!("{other:?}"),
    };
    assert_eq!(back.drivers_enabled(), Some(0x105));
    // An older controller: bit 3 clear, nothing per driver.
    let old = StatusReport {
        more_flags: MoreFlags(MoreFlags::ESTOP_LATCHED),
        ..status
    };
    assert_eq!(old.drivers_enabled(), None);
    assert_eq!(MoreFlags::of_enabled(0), MoreFlags::ENABLES_REPORTED);
}
