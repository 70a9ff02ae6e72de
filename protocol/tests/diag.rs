//! Issue 34 part C: STATUS's request byte bit 6 asks for the DIAG report (the board's own
//! timing counters); the report round-trips little-endian, is refused as a command, and
//! its figures convert to nanoseconds with the clocks it carries (none when a clock is 0).

use protocol::{Command, DecodeErrorKind, Diag, Report, StatusAsk, StatusCode, Tag, crc8, size};

#[test]
fn the_request_byte_bit_6_asks_for_diag() {
    let ask = StatusAsk {
        look_only: true,
        counters: true,
        diag: true,
        ..StatusAsk::default()
    };
    assert_eq!(ask.byte(), 0x4a);
    let mut buf = [0u8; 8];
    let n = Command::StatusWith(ask).encode(0x31, &mut buf).unwrap();
    assert_eq!(&buf[..n], &[0x31, 0x15, 0x4a, crc8(&[0x31, 0x15, 0x4a])]);
    assert_eq!(
        Command::decode(&buf[..n]).unwrap().body,
        Command::StatusWith(ask)
    );
    assert_eq!(StatusAsk::from_byte(0x40).map(|a| a.diag), Some(true));
    assert_eq!(StatusAsk::from_byte(0x08).map(|a| a.diag), Some(false));
    // Bit 7 stays INVALID_CONFIG (bits 4-5 are other issues' this round).
    let frame = [0x22, 0x15, 0xc0, crc8(&[0x22, 0x15, 0xc0])];
    let e = Command::decode(&frame).unwrap_err();
    assert_eq!(e.status(), Some(StatusCode::InvalidConfig));
}

fn example() -> Diag {
    Diag {
        cpu_hz: 400_000_000,
        masked_max_cycles: 812,
        masked_opener: 0x0801_2345,
        masked_spans: 96_000,
        step_hz: 200_000_000,
        dir_late_max_ticks: 37,
        dir_writes: 24,
        dma_slack_min_ticks: 4_321,
        dma_refills: 51_200,
    }
}

#[test]
fn diag_round_trips_little_endian() {
    let diag = example();
    let mut buf = [0u8; 64];
    let n = Report::Diag(diag).encode(0x2f, &mut buf).unwrap();
    assert_eq!(n, size::DIAG + 3);
    assert_eq!(
        &buf[..6],
        &[0x2f, Tag::Diag as u8, 0x00, 0x84, 0xd7, 0x17],
        "cpu_hz 400 MHz, little-endian"
    );
    assert_eq!(&buf[10..14], &[0x45, 0x23, 0x01, 0x08], "the opener");
    assert_eq!(Report::decode(&buf[..n]).unwrap().body, Report::Diag(diag));
    // A negative lateness (an early write) survives the trip.
    let early = Diag {
        dir_late_max_ticks: -3,
        ..diag
    };
    let n = Report::Diag(early).encode(0x30, &mut buf).unwrap();
    assert_eq!(Report::decode(&buf[..n]).unwrap().body, Report::Diag(early));
    assert_eq!(early.dir_late_max_ns(), Some(-15));
    // Short data is refused, and DIAG is never a command.
    let short = [0x30, 0x32, 0, crc8(&[0x30, 0x32, 0])];
    assert!(matches!(
        Report::decode(&short).unwrap_err().kind,
        DecodeErrorKind::BadLength { .. }
    ));
    let e = Command::decode(&buf[..n]).unwrap_err();
    assert_eq!(e.kind, DecodeErrorKind::WrongDirection);
}

#[test]
fn figures_convert_with_the_clocks_the_report_carries() {
    let diag = example();
    assert_eq!(diag.masked_max_ns(), Some(2_030));
    assert_eq!(diag.dir_late_max_ns(), Some(185));
    assert_eq!(diag.dma_slack_min_ns(), Some(21_605));
    // Not measured: no figure, whatever the counts say.
    let none = Diag::NOT_MEASURED;
    assert_eq!(none.masked_max_ns(), None);
    assert_eq!(none.dir_late_max_ns(), None);
    assert_eq!(none.dma_slack_min_ns(), None);
    // Measured, but nothing happened yet.
    let idle = Diag {
        dir_late_max_ticks: Diag::NO_DIR_WRITE,
        dma_slack_min_ticks: Diag::NO_REFILL,
        ..diag
    };
    assert_eq!(idle.dir_late_max_ns(), None);
    assert_eq!(idle.dma_slack_min_ns(), None);
    // The largest counts do not overflow.
    let big = Diag {
        masked_max_cycles: u32::MAX,
        dir_late_max_ticks: i32::MAX,
        ..diag
    };
    assert_eq!(big.masked_max_ns(), Some(10_737_418_237));
    assert_eq!(big.dir_late_max_ns(), Some(10_737_418_235));
}
