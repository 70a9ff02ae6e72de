//! Issue 33, limit switches (PROTOCOL.md, "Limit switches and UNLOCK"): the UNLOCK
//! command (0x25, no data) and the status code LIMIT_LATCHED (16).

use protocol::{Command, DecodeErrorKind, ExpectedLen, StatusCode, Tag, crc8};

#[test]
fn unlock_is_tag_0x25_without_data() {
    assert_eq!(Tag::from_u8(0x25), Some(Tag::Unlock));
    assert_eq!(Tag::Unlock.name(), "UNLOCK");
    assert_eq!(Command::Unlock.tag(), Tag::Unlock);
    let mut buf = [0u8; 8];
    let n = Command::Unlock.encode(0x21, &mut buf).unwrap();
    assert_eq!(&buf[..n], &[0x21, 0x25, crc8(&[0x21, 0x25])]);
    assert_eq!(Command::decode(&buf[..n]).unwrap().body, Command::Unlock);
    let with_data = [0x22, 0x25, 0x01, crc8(&[0x22, 0x25, 0x01])];
    let e = Command::decode(&with_data).unwrap_err();
    assert_eq!(
        e.kind,
        DecodeErrorKind::BadLength {
            expected: ExpectedLen::Exactly(0),
            found: 1
        }
    );
}

#[test]
fn limit_latched_is_status_16_and_may_change_on_a_resend() {
    assert_eq!(StatusCode::from_u8(16), Some(StatusCode::LimitLatched));
    assert_eq!(StatusCode::LimitLatched.name(), "LIMIT_LATCHED");
    assert!(!StatusCode::LimitLatched.refuses_for_good());
    assert!(StatusCode::LimitLatched.advice().contains("unlock"));
}
