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

#[test]
fn status_takes_one_request_byte_and_release_none() {
    use protocol::StatusAsk;
    assert_eq!(Tag::Release as u8, 0x19);
    let look = StatusAsk {
        location: true,
        look_only: true,
        stop_cause: false,
        counters: false,
        diag: false,
        motion: false,
    };
    let bytes = encode(Command::StatusWith(look), 0x1d);
    assert_eq!(&bytes[..3], &[0x1d, 0x15, 0x03]);
    assert_eq!(
        Command::decode(&bytes).unwrap().body,
        Command::StatusWith(look)
    );
    // No data: the plain STATUS of old hosts, unchanged.
    assert_eq!(
        Command::decode(&with_crc(vec![1, 0x15])).unwrap().body,
        Command::Status
    );
    let kind = |data: &[u8]| {
        Command::decode(&with_crc([&[1, 0x15][..], data].concat()))
            .unwrap_err()
            .kind
    };
    // Bit 2 (the STOP_CAUSE report) is defined since issue 31, bit 3 (RX_COUNTERS) since
    // issue 30 and bit 4 (MOTION) since issue 32 (this asserted 0x08, then 0x10, refused
    // before); bit 7 stays undefined.
    assert_eq!(kind(&[0x80]), DecodeErrorKind::OutOfRange(Field::StatusAsk));
    assert!(matches!(kind(&[0, 0]), DecodeErrorKind::BadLength { .. }));
    for b in 0..=31u8 {
        assert_eq!(StatusAsk::from_byte(b).map(StatusAsk::byte), Some(b));
    }
    let release = encode(Command::Release, 0x1e);
    assert_eq!(&release[..2], &[0x1e, 0x19]);
    assert_eq!(release.len(), 3);
    assert_eq!(Command::decode(&release).unwrap().body, Command::Release);
    assert!(matches!(
        Command::decode(&with_crc(vec![1, 0x19, 0]))
            .unwrap_err()
            .kind,
        DecodeErrorKind::BadLength { .. }
    ));
}

#[test]
fn limits_set_get_and_the_limits_report() {
    use protocol::{JointLimits, LimitsReport, LimitsSet, Refusal, RefusalReason};
    assert_eq!(
        (
            Tag::LimitsSet as u8,
            Tag::LimitsGet as u8,
            Tag::Limits as u8
        ),
        (0x1a, 0x1b, 0x1c)
    );
    let set = LimitsSet {
        joint: 1,
        limits: JointLimits {
            min: -16_000,
            max: 16_000,
            max_rate_hz: 4_000,
        },
    };
    let bytes = encode(Command::LimitsSet(set), 0x1f);
    assert_eq!(bytes.len(), 3 + 16);
    assert_eq!(&bytes[2..6], &[1, 0, 0, 0]);
    assert_eq!(&bytes[6..10], &(-16_000i32).to_le_bytes());
    assert_eq!(&bytes[10..14], &16_000i32.to_le_bytes());
    assert_eq!(&bytes[14..18], &4_000u32.to_le_bytes());
    assert_eq!(
        Command::decode(&bytes).unwrap().body,
        Command::LimitsSet(set)
    );
    // Joint 8, min above max: INVALID_CONFIG; other lengths: BAD_LENGTH.
    let mut bad = bytes[..18].to_vec();
    bad[2] = 8;
    assert_eq!(
        Command::decode(&with_crc(bad)).unwrap_err().kind,
        DecodeErrorKind::OutOfRange(Field::JointLimits)
    );
    let mut bad = bytes[..18].to_vec();
    bad[6..10].copy_from_slice(&20_000i32.to_le_bytes());
    assert_eq!(
        Command::decode(&with_crc(bad)).unwrap_err().kind,
        DecodeErrorKind::OutOfRange(Field::JointLimits)
    );
    assert!(matches!(
        Command::decode(&with_crc(bytes[..17].to_vec()))
            .unwrap_err()
            .kind,
        DecodeErrorKind::BadLength { .. }
    ));
    assert_eq!(
        Command::decode(&with_crc(vec![3, 0x1b])).unwrap().body,
        Command::LimitsGet
    );
    // The report: 8 x 12 bytes of limits, then the refusal (16 bytes).
    let mut joints = [JointLimits::NONE; 8];
    joints[1] = set.limits;
    let report = LimitsReport {
        max_accel: None,
        joints,
        last_refusal: Refusal {
            seq: 0x21,
            tag: 0x01,
            point: 3,
            joint: 1,
            reason: RefusalReason::AboveMax,
            value: 16_100,
            limit: 16_000,
        },
    };
    let mut buf = [0u8; 200];
    let n = Report::Limits(report).encode(0x2c, &mut buf).unwrap();
    assert_eq!(n, 3 + 112);
    assert_eq!(&buf[2 + 96..2 + 101], &[0x21, 0x01, 3, 1, 2]);
    assert_eq!(
        Report::decode(&buf[..n]).unwrap().body,
        Report::Limits(report)
    );
    // A host may not send the report.
    assert_eq!(
        Command::decode(&buf[..n]).unwrap_err().kind,
        DecodeErrorKind::WrongDirection
    );
}
