//! Properties of the wire format over arbitrary values: every command and report survives
//! encode then decode, no byte string makes a decoder panic, every single-bit error is
//! caught by the CRC, and `Point::from_motion` fills the timer hints by the rules of
//! docs/PROTOCOL.md, "Point (116 bytes): one segment of a trajectory".

use proptest::prelude::*;
use protocol::{
    Ack, Command, DecodeErrorKind, Location, MAX_DATAGRAM, MAX_JOINTS, MAX_POINTS_PER_FRAME,
    MAX_SERIAL_CHUNK, Point, PointList, Pwm, Report, State, StatusCode, StatusFlags, StatusReport,
    UartInit, crc8, limits,
};

/// An owned command, so that strategies can produce the borrowed parts
/// (`PENDING`'s points, `USART_SEND`'s bytes).
#[derive(Clone, Debug)]
enum OwnedCommand {
    Pending(Vec<Point>),
    UsartSend(Vec<u8>),
    /// Every command without borrowed parts.
    Plain(Command<'static>),
}

impl OwnedCommand {
    fn command(&self) -> Command<'_> {
        match self {
            OwnedCommand::Pending(points) => Command::Pending(PointList::Points(points)),
            OwnedCommand::UsartSend(bytes) => Command::UsartSend(bytes),
            OwnedCommand::Plain(cmd) => *cmd,
        }
    }
}

/// Same for reports (`USART_RECV`'s bytes).
#[derive(Clone, Debug)]
enum OwnedReport {
    UsartRecv(Vec<u8>),
    Plain(Report<'static>),
}

impl OwnedReport {
    fn report(&self) -> Report<'_> {
        match self {
            OwnedReport::UsartRecv(bytes) => Report::UsartRecv(bytes),
            OwnedReport::Plain(report) => *report,
        }
    }
}

fn joints_i32() -> impl Strategy<Value = [i32; MAX_JOINTS]> {
    prop::array::uniform8(any::<i32>())
}

fn joints_i16() -> impl Strategy<Value = [i16; MAX_JOINTS]> {
    prop::array::uniform8(any::<i16>())
}

/// A point decode accepts: duration >= 1, anything in the hint arrays.
fn point() -> impl Strategy<Value = Point> {
    (
        1..=i32::MAX,
        joints_i16(),
        joints_i16(),
        joints_i16(),
        joints_i32(),
        joints_i32(),
    )
        .prop_map(|(duration, full, rest, count, period, position)| Point {
            duration,
            number_of_full_period: full,
            rest_period: rest,
            number_of_period: count,
            period,
            position,
        })
}

fn state() -> impl Strategy<Value = State> {
    prop_oneof![
        Just(State::New),
        Just(State::Pending),
        Just(State::Running),
        Just(State::Stopped),
    ]
}

fn status_code() -> impl Strategy<Value = StatusCode> {
    (0u8..=12).prop_map(|b| StatusCode::from_u8(b).expect("0..=12 are all codes"))
}

fn pwm() -> impl Strategy<Value = Pwm> {
    (0u32..=0xFFFF, 0u32..=0xFFFF, any::<i32>()).prop_flat_map(|(psc, arr, pulse_count)| {
        (0..=arr).prop_map(move |ccr1| Pwm {
            psc,
            arr,
            ccr1,
            pulse_count,
        })
    })
}

fn uart_init() -> impl Strategy<Value = UartInit> {
    (limits::BAUD_RATE, prop::array::uniform6(any::<u32>())).prop_map(|(baud_rate, w)| UartInit {
        baud_rate,
        word_length: w[0],
        stop_bits: w[1],
        parity: w[2],
        mode: w[3],
        hw_flow_ctl: w[4],
        over_sampling: w[5],
    })
}

/// Every command variant with every value decode accepts.
fn command() -> impl Strategy<Value = OwnedCommand> {
    use Command as C;
    let plain = prop_oneof![
        (1..=u16::MAX).prop_map(|count| C::New { count }),
        Just(C::Runing),
        Just(C::Stopped),
        Just(C::UploadStart),
        Just(C::UploadStop),
        pwm().prop_map(C::PwmStart),
        Just(C::PwmStop),
        uart_init().prop_map(C::UsartStart),
        Just(C::UsartStop),
        Just(C::Pin0On),
        Just(C::Pin0Off),
        Just(C::Pin1On),
        Just(C::Pin1Off),
        prop::option::of(0..=limits::ENABLE_MASK_BITS)
            .prop_map(|mask| C::ToggleEnablePins { mask }),
        Just(C::Return),
        limits::JOINTS.prop_map(C::JointsCount),
        (joints_i32(), any::<u8>())
            .prop_map(|(position, state)| C::LocationSetting(Location { position, state })),
        Just(C::Status),
        limits::UPLOAD_PERIOD_US.prop_map(|period_us| C::UploadPeriod { period_us }),
        Just(C::EstopReset),
    ];
    prop_oneof![
        prop::collection::vec(point(), 1..=MAX_POINTS_PER_FRAME).prop_map(OwnedCommand::Pending),
        prop::collection::vec(any::<u8>(), 1..=MAX_SERIAL_CHUNK).prop_map(OwnedCommand::UsartSend),
        plain.prop_map(OwnedCommand::Plain),
    ]
}

fn status_report() -> impl Strategy<Value = StatusReport> {
    (
        prop::array::uniform3(any::<u8>()),
        any::<u8>(),
        state(),
        any::<u8>(),
        prop::array::uniform7(any::<u16>()),
        prop::array::uniform4(any::<u32>()),
    )
        .prop_map(
            |(version, joints, state, flags, counts, words)| StatusReport {
                version,
                joints,
                state,
                flags: StatusFlags(flags),
                window: counts[5],
                more_flags: protocol::MoreFlags(counts[6]),
                buffered: counts[0],
                expected: counts[1],
                received: counts[2],
                executed: counts[3],
                capacity: counts[4],
                upload_period_us: words[0],
                pwm_timer_clock_hz: words[1],
                max_step_rate_hz: words[2],
                step_budget_hz: words[3],
            },
        )
}

/// Every report variant with every value decode accepts.
fn report() -> impl Strategy<Value = OwnedReport> {
    let ack = (
        any::<u8>(),
        status_code(),
        state(),
        any::<u8>(),
        any::<u16>(),
        any::<u16>(),
    )
        .prop_map(|(acked_tag, status, state, next_seq, buffered, free)| {
            Report::Ack(Ack {
                acked_tag,
                status,
                state,
                next_seq,
                buffered,
                free,
            })
        });
    let location = (joints_i32(), state()).prop_map(|(position, state)| {
        Report::Location(Location {
            position,
            state: state as u8,
        })
    });
    prop_oneof![
        prop::collection::vec(any::<u8>(), 0..=MAX_SERIAL_CHUNK).prop_map(OwnedReport::UsartRecv),
        ack.prop_map(OwnedReport::Plain),
        location.prop_map(OwnedReport::Plain),
        status_report().prop_map(|s| OwnedReport::Plain(Report::Status(s))),
    ]
}

fn encode_command(cmd: &Command<'_>, seq: u8) -> Vec<u8> {
    let mut buf = [0u8; MAX_DATAGRAM];
    let n = cmd.encode(seq, &mut buf).expect("a valid command encodes");
    buf[..n].to_vec()
}

fn encode_report(report: &Report<'_>, seq: u8) -> Vec<u8> {
    let mut buf = [0u8; MAX_DATAGRAM];
    let n = report
        .encode(seq, &mut buf)
        .expect("a valid report encodes");
    buf[..n].to_vec()
}

/// Any frame: arbitrary seq, tag near the table, arbitrary data, correct CRC.
fn frame_with_valid_crc() -> impl Strategy<Value = Vec<u8>> {
    (
        any::<u8>(),
        0u8..=0x20,
        prop::collection::vec(any::<u8>(), 0..=MAX_DATAGRAM - 3),
    )
        .prop_map(|(seq, tag, data)| {
            let mut frame = vec![seq, tag];
            frame.extend_from_slice(&data);
            frame.push(crc8(&frame));
            frame
        })
}

/// A decoded frame, whatever it is, re-encodes and decodes to itself.
fn assert_stable(bytes: &[u8]) -> Result<(), TestCaseError> {
    if let Ok(frame) = Command::decode(bytes) {
        let again = encode_command(&frame.body, frame.seq);
        prop_assert_eq!(Command::decode(&again), Ok(frame));
    }
    if let Ok(frame) = Report::decode(bytes) {
        let again = encode_report(&frame.body, frame.seq);
        prop_assert_eq!(Report::decode(&again), Ok(frame));
    }
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(1000))]

    #[test]
    fn command_round_trips(cmd in command(), seq in any::<u8>()) {
        let cmd = cmd.command();
        let bytes = encode_command(&cmd, seq);
        prop_assert_eq!(bytes.len(), cmd.encoded_len());
        prop_assert!(bytes.len() <= MAX_DATAGRAM);
        let frame = Command::decode(&bytes);
        prop_assert_eq!(frame.map(|f| (f.seq, f.body)), Ok((seq, cmd)));
    }

    #[test]
    fn report_round_trips(report in report(), seq in any::<u8>()) {
        let report = report.report();
        let bytes = encode_report(&report, seq);
        prop_assert_eq!(bytes.len(), report.encoded_len());
        let frame = Report::decode(&bytes);
        prop_assert_eq!(frame.map(|f| (f.seq, f.body)), Ok((seq, report)));
    }

    #[test]
    fn decode_never_panics_on_arbitrary_bytes(
        bytes in prop::collection::vec(any::<u8>(), 0..=MAX_DATAGRAM + 8)
    ) {
        assert_stable(&bytes)?;
    }

    /// Past the CRC check, so the length and range checks see arbitrary data.
    #[test]
    fn decode_never_panics_past_the_crc(bytes in frame_with_valid_crc()) {
        assert_stable(&bytes)?;
    }

    /// CRC-8 with polynomial 0x07 detects every single-bit error, so a flipped bit
    /// anywhere (seq, tag, data or the CRC byte itself) must give BAD_CRC.
    #[test]
    fn a_flipped_bit_in_a_command_is_bad_crc(cmd in command(), seq in any::<u8>(), bit in any::<prop::sample::Index>()) {
        let mut bytes = encode_command(&cmd.command(), seq);
        let bit = bit.index(bytes.len() * 8);
        bytes[bit / 8] ^= 1 << (bit % 8);
        let err = Command::decode(&bytes).expect_err("a damaged frame is refused");
        prop_assert!(matches!(err.kind, DecodeErrorKind::BadCrc { .. }), "{:?}", err);
        prop_assert_eq!(err.status(), Some(StatusCode::BadCrc));
    }

    #[test]
    fn a_flipped_bit_in_a_report_is_bad_crc(report in report(), seq in any::<u8>(), bit in any::<prop::sample::Index>()) {
        let mut bytes = encode_report(&report.report(), seq);
        let bit = bit.index(bytes.len() * 8);
        bytes[bit / 8] ^= 1 << (bit % 8);
        let err = Report::decode(&bytes).expect_err("a damaged frame is refused");
        prop_assert!(matches!(err.kind, DecodeErrorKind::BadCrc { .. }), "{:?}", err);
    }

    /// The hint rules, checked per joint with wide arithmetic.
    #[test]
    fn from_motion_fills_the_hints(
        duration in 1..=i32::MAX,
        previous in joints_i32(),
        // Small moves as well as huge ones, so both sides of the split are reached.
        delta in prop::array::uniform8(prop_oneof![-3i64..=3, -100_000i64..=100_000, any::<i32>().prop_map(i64::from)]),
    ) {
        let target: [i32; MAX_JOINTS] = core::array::from_fn(|j| {
            (i64::from(previous[j]) + delta[j]).clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32
        });
        let p = Point::from_motion(duration, &previous, &target);
        prop_assert_eq!(p.duration, duration);
        prop_assert_eq!(p.position, target);
        for j in 0..MAX_JOINTS {
            let n = (i64::from(target[j]) - i64::from(previous[j])).unsigned_abs();
            if n == 0 {
                prop_assert_eq!(
                    (p.number_of_period[j], p.period[j], p.number_of_full_period[j], p.rest_period[j]),
                    (0, 0, 0, 0)
                );
                continue;
            }
            // numberOfPeriod: the low 16 bits of N.
            prop_assert_eq!(p.number_of_period[j] as u16 as u64, n % 65_536);
            let period = duration as u64 / n;
            prop_assert_eq!(p.period[j] as u64, period);
            if period > 0xFFFF {
                prop_assert_eq!(p.number_of_full_period[j] as u16 as u64, period / 65_536);
                prop_assert_eq!(p.rest_period[j] as u16 as u64, period % 65_536);
                // The split puts the period back together.
                prop_assert_eq!(
                    (p.number_of_full_period[j] as u16 as u64) * 65_536 + p.rest_period[j] as u16 as u64,
                    period
                );
            } else {
                prop_assert_eq!((p.number_of_full_period[j], p.rest_period[j]), (0, 0));
            }
        }
    }
}

#[test]
fn crc8_check_value() {
    assert_eq!(crc8(b"123456789"), 0xF4);
    assert_eq!(crc8(b""), 0x00);
}

/// Worked cases of the hint rules, beside the golden slow point in `golden.rs`.
#[test]
fn from_motion_examples() {
    let zero = [0; MAX_JOINTS];
    // 100 steps backwards in 1 s: period 10000 us, no split.
    let mut target = zero;
    target[2] = -100;
    let p = Point::from_motion(1_000_000, &zero, &target);
    assert_eq!(p.number_of_period[2], 100);
    assert_eq!(p.period[2], 10_000);
    assert_eq!((p.number_of_full_period[2], p.rest_period[2]), (0, 0));
    // Joints that do not move are all zeros.
    assert_eq!(p.number_of_period[0], 0);
    assert_eq!(p.period[0], 0);
    // 1 step in 0x1_8000 us: the split with a rest above i16::MAX keeps its u16 bits.
    target[2] = 1;
    let p = Point::from_motion(0x1_8000, &zero, &target);
    assert_eq!(p.period[2], 0x1_8000);
    assert_eq!(p.number_of_full_period[2], 1);
    assert_eq!(p.rest_period[2] as u16, 0x8000);
    // 70000 steps: numberOfPeriod is N truncated to 16 bits; period 0 (floor).
    target[2] = 70_000;
    let p = Point::from_motion(1_000, &zero, &target);
    assert_eq!(p.number_of_period[2] as u16, (70_000u32 & 0xFFFF) as u16);
    assert_eq!(p.period[2], 0);
}

#[test]
fn encode_refuses_what_cannot_be_a_frame() {
    let mut buf = [0u8; MAX_DATAGRAM];
    let points = [Point {
        duration: 1,
        ..Point::default()
    }; MAX_POINTS_PER_FRAME + 1];
    assert!(
        Command::Pending(PointList::Points(&[]))
            .encode(0, &mut buf)
            .is_err()
    );
    assert!(
        Command::Pending(PointList::Points(&points))
            .encode(0, &mut buf)
            .is_err()
    );
    assert!(
        Command::Pending(PointList::Wire(&[1u8; 117]))
            .encode(0, &mut buf)
            .is_err()
    );
    assert!(Command::UsartSend(&[]).encode(0, &mut buf).is_err());
    assert!(Command::UsartSend(&[0; 256]).encode(0, &mut buf).is_err());
    assert!(Report::UsartRecv(&[0; 256]).encode(0, &mut buf).is_err());
    // A buffer one byte short.
    let cmd = Command::UploadPeriod { period_us: 10_000 };
    let mut short = [0u8; 6];
    assert!(cmd.encode(0, &mut short).is_err());
    assert_eq!(cmd.encode(0, &mut buf), Ok(7));
}

#[test]
fn location_report_with_an_unknown_state_is_refused() {
    let report = Report::Location(Location {
        position: [0; MAX_JOINTS],
        state: 4,
    });
    let bytes = encode_report(&report, 1);
    assert!(Report::decode(&bytes).is_err());
}

#[test]
fn point_list_get_out_of_range_is_none() {
    let wire = [0u8; 116];
    let list = PointList::Wire(&wire);
    assert!(list.get(0).is_some());
    assert!(list.get(1).is_none());
    assert!(list.get(usize::MAX).is_none());
}
