//! Issue 30 part 4: STATUS's request byte bit 3 asks for the RX_COUNTERS report (the
//! receive path's drops; bit 2 is issue 31's STOP_CAUSE, and both may be asked
//! together); the report round-trips, is refused as a command, and a byte with bit 7 set is
//! still INVALID_CONFIG (bit 4 is issue 32's MOTION).

use protocol::{
    Command, DecodeErrorKind, Field, Report, RxCounters, StatusAsk, StatusCode, Tag, crc8, size,
};

#[test]
fn the_request_byte_bit_3_asks_for_rx_counters() {
    let ask = StatusAsk {
        location: false,
        look_only: true,
        stop_cause: false,
        counters: true,
        diag: false,
        motion: false,
    };
    assert_eq!(ask.byte(), 0x0a);
    let mut buf = [0u8; 8];
    let n = Command::StatusWith(ask).encode(0x21, &mut buf).unwrap();
    assert_eq!(&buf[..n], &[0x21, 0x15, 0x0a, crc8(&[0x21, 0x15, 0x0a])]);
    assert_eq!(
        Command::decode(&buf[..n]).unwrap().body,
        Command::StatusWith(ask)
    );
    // With the STOP_CAUSE (bit 2) as well: both reports asked in one STATUS.
    let both = StatusAsk {
        stop_cause: true,
        ..ask
    };
    assert_eq!(both.byte(), 0x0e);
    assert_eq!(
        StatusAsk::from_byte(0x0c).map(|a| (a.stop_cause, a.counters)),
        Some((true, true))
    );
    // Bit 2 is STOP_CAUSE's, not this report's (it asserted 0x08 refused before issue 31's
    // bit 2 moved RX_COUNTERS to bit 3).
    assert_eq!(StatusAsk::from_byte(0x04).map(|a| a.counters), Some(false));
    // 0x10 is bit 4 since issue 32 (the MOTION report): this refused [0x10, 0x80] before.
    let frame = [0x22, 0x15, 0x80, crc8(&[0x22, 0x15, 0x80])];
    let e = Command::decode(&frame).unwrap_err();
    assert_eq!(e.kind, DecodeErrorKind::OutOfRange(Field::StatusAsk));
    assert_eq!(e.status(), Some(StatusCode::InvalidConfig));
}

#[test]
fn rx_counters_round_trip_little_endian() {
    let counters = RxCounters {
        ring_dropped: 0x0102_0304,
        ring_full: 5,
        interrupt_stops: 20,
        shed: 70_000,
        inbox_dropped: 1,
        group_ignored: u32::MAX,
    };
    let mut buf = [0u8; 64];
    let n = Report::RxCounters(counters).encode(0x30, &mut buf).unwrap();
    assert_eq!(n, size::RX_COUNTERS + 3);
    assert_eq!(&buf[..6], &[0x30, Tag::RxCounters as u8, 4, 3, 2, 1]);
    assert_eq!(
        Report::decode(&buf[..n]).unwrap().body,
        Report::RxCounters(counters)
    );
    // Any other length is refused; as a command it travels the wrong way.
    let short = [0x30, 0x24, 0, crc8(&[0x30, 0x24, 0])];
    assert!(Report::decode(&short).is_err());
    let e = Command::decode(&buf[..n]).unwrap_err();
    assert_eq!(e.kind, DecodeErrorKind::WrongDirection);
}
