//! Issue 31 on the wire (ACCEL_SET at the end): the stop cause: STATUS `more_flags` bits 5-7, STATUS's request byte
//! bit 2 and the STOP_CAUSE report (docs/PROTOCOL.md, STATUS "What ended the last run").

use protocol::{Command, MoreFlags, Report, StatusAsk, StatusReport, StopCause, StopReport, Tag};

#[test]
fn stop_cause_report_round_trips_at_its_offsets() {
    let stop = StopReport {
        from_ip: [127, 0, 0, 2],
        from_port: 40_001,
        ..StopReport::of(StopCause::Stopped)
    };
    let mut buf = [0u8; 64];
    let n = Report::StopCause(stop).encode(0x32, &mut buf).unwrap();
    assert_eq!(n, protocol::size::STOP_CAUSE + 3);
    assert_eq!(buf[1], Tag::StopCause as u8);
    assert_eq!(
        &buf[2..14],
        &[2, 0, 0, 0, 127, 0, 0, 2, 0x41, 0x9c, 0, 0],
        "cause, detail, reserved, address, port, reserved"
    );
    let frame = Report::decode(&buf[..n]).unwrap();
    assert_eq!(frame.body, Report::StopCause(stop));
    // Any other length is refused; a host may not send it.
    assert!(Report::decode(&protocol_frame(0x1d, &[0; 11])).is_err());
    assert!(Command::decode(&buf[..n]).is_err());
    // A cause byte from a newer controller decodes as unknown, not as an error.
    let mut newer = buf;
    newer[2] = 9;
    newer[n - 1] = protocol::crc8(&newer[..n - 1]);
    let Report::StopCause(s) = Report::decode(&newer[..n]).unwrap().body else {
        panic!("a STOP_CAUSE report")
    };
    assert_eq!(s.cause, None);
}

fn protocol_frame(tag: u8, data: &[u8]) -> Vec<u8> {
    let mut v = vec![0x01, tag];
    v.extend_from_slice(data);
    v.push(protocol::crc8(&v));
    v
}

#[test]
fn more_flags_bits_5_to_7_carry_the_cause_and_0_is_not_reported() {
    let mut s = StatusReport::default();
    assert_eq!(s.stop_cause(), None, "an older controller sends 0");
    for &cause in StopCause::ALL {
        s.more_flags = MoreFlags(0xFF1F | MoreFlags::of_stop_cause(cause));
        assert_eq!(s.stop_cause(), Some(cause));
        assert_eq!(
            s.drivers_enabled(),
            Some(0x1FF),
            "the other bits stay theirs"
        );
    }
    assert_eq!(StopCause::EstopInput.name(), "ESTOP_INPUT");
}

#[test]
fn status_request_bit_2_asks_for_the_stop_cause() {
    let ask = StatusAsk {
        stop_cause: true,
        ..StatusAsk::default()
    };
    assert_eq!(ask.byte(), 0x04);
    let mut buf = [0u8; 8];
    let n = Command::StatusWith(ask).encode(0x30, &mut buf).unwrap();
    assert_eq!(&buf[..n - 1], &[0x30, 0x15, 0x04]);
    let Command::StatusWith(back) = Command::decode(&buf[..n]).unwrap().body else {
        panic!("STATUS with a request byte")
    };
    assert_eq!(back, ask);
    assert_eq!(StatusAsk::from_byte(0x07).map(|a| a.byte()), Some(0x07));
    // Bit 3 asks for issue 30's RX_COUNTERS (this asserted 0x08 refused before the merge).
    assert_eq!(StatusAsk::from_byte(0x08).map(|a| a.counters), Some(true));
    // Bit 4 asks for issue 32's MOTION (this asserted 0x10 refused before it); bit 7
    // stays undefined.
    assert_eq!(StatusAsk::from_byte(0x10).map(|a| a.motion), Some(true));
    assert_eq!(StatusAsk::from_byte(0x80), None, "bit 7 is not defined");
}

/// Issue 31's ACCEL_SET and LIMITS_GET's request byte: the LIMITS report with the
/// accelerations after its 112 bytes, and the 112 bytes alone for old hosts.
#[test]
fn accel_set_and_the_limits_report_with_accelerations() {
    let mut buf = [0u8; 256];
    let set = Command::AccelSet {
        joint: 2,
        max_accel_steps_s2: 100_000,
    };
    let n = set.encode(0x23, &mut buf).unwrap();
    assert_eq!(
        &buf[..n - 1],
        &[0x23, 0x1e, 2, 0, 0, 0, 0xa0, 0x86, 0x01, 0]
    );
    assert_eq!(Command::decode(&buf[..n]).unwrap().body, set);
    let bad = protocol_frame(0x1e, &[8, 0, 0, 0, 1, 0, 0, 0]);
    assert_eq!(
        Command::decode(&bad).unwrap_err().status(),
        Some(protocol::StatusCode::InvalidConfig)
    );
    let n = Command::LimitsGetWithAccel.encode(0x24, &mut buf).unwrap();
    assert_eq!(&buf[..n - 1], &[0x24, 0x1b, 0x01]);
    assert_eq!(
        Command::decode(&buf[..n]).unwrap().body,
        Command::LimitsGetWithAccel
    );
    let other = protocol_frame(0x1b, &[0x02]);
    assert_eq!(
        Command::decode(&other).unwrap_err().status(),
        Some(protocol::StatusCode::InvalidConfig)
    );
    let mut accel = [0u32; protocol::MAX_JOINTS];
    accel[2] = 100_000;
    let report = protocol::LimitsReport {
        max_accel: Some(accel),
        ..protocol::LimitsReport::default()
    };
    let n = Report::Limits(report).encode(0x2e, &mut buf).unwrap();
    assert_eq!(n, protocol::size::LIMITS_WITH_ACCEL + 3);
    assert_eq!(&buf[2 + 112 + 8..2 + 112 + 12], &100_000u32.to_le_bytes());
    assert_eq!(
        Report::decode(&buf[..n]).unwrap().body,
        Report::Limits(report)
    );
    let plain = protocol::LimitsReport {
        max_accel: None,
        ..report
    };
    let n = Report::Limits(plain).encode(0x2f, &mut buf).unwrap();
    assert_eq!(n, protocol::size::LIMITS + 3, "old hosts' 112 bytes");
    assert_eq!(
        Report::decode(&buf[..n]).unwrap().body,
        Report::Limits(plain)
    );
}
