//! Issue 18, the wired e-stop input (PROTOCOL.md sections 4, 5 and 8): the ESTOP_RESET
//! command (0x17, no data), the status code ESTOP_LATCHED (12) and STATUS `more_flags`
//! bits 1 (input open) and 2 (latch set).

use protocol::{
    Command, DecodeErrorKind, ExpectedLen, MoreFlags, Report, StatusCode, StatusReport, Tag, crc8,
};

#[test]
fn estop_reset_is_tag_0x17_without_data() {
    assert_eq!(Tag::from_u8(0x17), Some(Tag::EstopReset));
    assert_eq!(Tag::EstopReset.name(), "ESTOP_RESET");
    assert_eq!(Command::EstopReset.tag(), Tag::EstopReset);
    let mut buf = [0u8; 8];
    let n = Command::EstopReset.encode(0x19, &mut buf).unwrap();
    assert_eq!(&buf[..n], &[0x19, 0x17, crc8(&[0x19, 0x17])]);
    assert_eq!(
        Command::decode(&buf[..n]).unwrap().body,
        Command::EstopReset
    );
    // Data is refused, as for every command without data but STOPPED.
    let with_data = [0x1a, 0x17, 0x01, crc8(&[0x1a, 0x17, 0x01])];
    let e = Command::decode(&with_data).unwrap_err();
    assert_eq!(
        e.kind,
        DecodeErrorKind::BadLength {
            expected: ExpectedLen::Exactly(0),
            found: 1
        }
    );
    assert_eq!(e.status(), Some(StatusCode::BadLength));
}

#[test]
fn estop_latched_is_status_code_12() {
    assert_eq!(StatusCode::from_u8(12), Some(StatusCode::EstopLatched));
    assert_eq!(StatusCode::EstopLatched.name(), "ESTOP_LATCHED");
    assert_eq!(
        StatusCode::from_name("ESTOP_LATCHED"),
        Some(StatusCode::EstopLatched)
    );
    assert!(StatusCode::EstopLatched.advice().contains("ESTOP_RESET"));
}

#[test]
fn more_flags_carry_the_input_and_the_latch_at_offset_18() {
    assert_eq!(MoreFlags::ESTOP_OPEN, 1 << 1);
    assert_eq!(MoreFlags::ESTOP_LATCHED, 1 << 2);
    let status = StatusReport {
        more_flags: MoreFlags(MoreFlags::ESTOP_OPEN | MoreFlags::ESTOP_LATCHED),
        ..StatusReport::default()
    };
    let mut buf = [0u8; 64];
    let n = Report::Status(status).encode(3, &mut buf).unwrap();
    // seq, tag, then the 36 data bytes: more_flags is u16 little-endian at offset 18.
    assert_eq!(&buf[2 + 18..2 + 20], &[0b110, 0]);
    let Report::Status(back) = Report::decode(&buf[..n]).unwrap().body else {
        panic!("a STATUS report");
    };
    assert!(back.more_flags.has(MoreFlags::ESTOP_OPEN));
    assert!(back.more_flags.has(MoreFlags::ESTOP_LATCHED));
}
