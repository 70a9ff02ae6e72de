//! Issue 32: HOLD (0x27), RESUME (0x28) and OVERRIDE (0x29, percent 1..200) as commands,
//! MOTION (0x2a) as a report asked for with STATUS's request byte bit 4; each round-trips,
//! and what is out of range or travels the wrong way is refused.

use protocol::{
    Command, ControlledStop, DecodeErrorKind, Field, MotionFlags, MotionReport, OverrideLimit,
    Report, StatusAsk, StatusCode, Tag, crc8, size,
};

fn encode(cmd: Command<'_>, seq: u8) -> Vec<u8> {
    let mut buf = [0u8; 16];
    let n = cmd.encode(seq, &mut buf).expect("encodes");
    buf[..n].to_vec()
}

#[test]
fn hold_resume_and_override_round_trip() {
    assert_eq!(
        encode(Command::Hold, 0x10),
        vec![0x10, 0x27, crc8(&[0x10, 0x27])]
    );
    assert_eq!(
        encode(Command::Resume, 0x11),
        vec![0x11, 0x28, crc8(&[0x11, 0x28])]
    );
    assert_eq!(
        encode(Command::Override { percent: 50 }, 0x12),
        vec![0x12, 0x29, 50, crc8(&[0x12, 0x29, 50])]
    );
    for cmd in [
        Command::Hold,
        Command::Resume,
        Command::Override { percent: 1 },
        Command::Override { percent: 200 },
    ] {
        let bytes = encode(cmd, 7);
        assert_eq!(Command::decode(&bytes).expect("decodes").body, cmd);
    }
}

#[test]
fn out_of_range_or_wrong_length_is_refused() {
    for percent in [0u8, 201, 255] {
        let frame = [1, 0x29, percent, crc8(&[1, 0x29, percent])];
        let e = Command::decode(&frame).unwrap_err();
        assert_eq!(e.kind, DecodeErrorKind::OutOfRange(Field::Override));
        assert_eq!(e.status(), Some(StatusCode::InvalidConfig));
    }
    for frame in [
        vec![1, 0x27, 0, crc8(&[1, 0x27, 0])],
        vec![1, 0x29, crc8(&[1, 0x29])],
    ] {
        let e = Command::decode(&frame).unwrap_err();
        assert_eq!(e.status(), Some(StatusCode::BadLength), "{frame:?}");
    }
    // MOTION only goes from controller to host.
    let mut buf = [0u8; 16];
    let n = Report::Motion(MotionReport::IDLE)
        .encode(3, &mut buf)
        .unwrap();
    let e = Command::decode(&buf[..n]).unwrap_err();
    assert_eq!(e.kind, DecodeErrorKind::WrongDirection);
}

#[test]
fn motion_report_round_trips_and_status_bit_4_asks_for_it() {
    let report = MotionReport {
        factor_percent: 25,
        flags: MotionFlags(MotionFlags::HELD | MotionFlags::RAMPING),
        rate_permille: 0x0123,
        last_stop: Some(ControlledStop::Hold),
        refused_joint: 3,
        refused_limit: Some(OverrideLimit::Accel),
        estop_category: Some(protocol::EStopCategory::Instant),
    };
    let mut buf = [0u8; 16];
    let n = Report::Motion(report).encode(0x40, &mut buf).unwrap();
    assert_eq!(n, size::MOTION + 3);
    assert_eq!(
        &buf[..n - 1],
        &[0x40, Tag::Motion as u8, 25, 0x05, 0x23, 0x01, 1, 3, 2, 0]
    );
    assert_eq!(
        Report::decode(&buf[..n]).unwrap().body,
        Report::Motion(report)
    );
    let ask = StatusAsk {
        motion: true,
        ..StatusAsk::default()
    };
    assert_eq!(ask.byte(), 0x10);
    assert_eq!(StatusAsk::from_byte(0x1f).map(|a| a.motion), Some(true));
    assert_eq!(StatusAsk::from_byte(0x80), None);
}
