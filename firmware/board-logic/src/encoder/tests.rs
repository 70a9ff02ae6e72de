//! The Modbus codec, the timing and the reads of every joint, against fake buses.

use super::*;
use embassy_futures::block_on;
use proptest::prelude::*;
use std::collections::VecDeque;
use std::vec::Vec;

#[test]
fn request_matches_the_modbus_specification_example() {
    // Address 1, read 2 registers from 0: the CRC every Modbus tool prints.
    assert_eq!(
        position_request(1, 0),
        [0x01, 0x03, 0x00, 0x00, 0x00, 0x02, 0xC4, 0x0B]
    );
    assert_eq!(
        parse_position_request(&position_request(7, 0x10)),
        Some((7, 0x10))
    );
    let mut bad = position_request(7, 0x10);
    bad[3] ^= 1;
    assert_eq!(parse_position_request(&bad), None);
}

#[test]
fn replies_are_checked() {
    let good = position_reply(3, -123_456);
    assert_eq!(parse_position_reply(3, &good), Ok(-123_456));
    assert_eq!(parse_position_reply(4, &good), Err(ReplyError::Unexpected));
    let mut bad_crc = good;
    bad_crc[4] ^= 0x10;
    assert_eq!(parse_position_reply(3, &bad_crc), Err(ReplyError::BadCrc));
    assert_eq!(parse_position_reply(3, &good[..6]), Err(ReplyError::Short));
    assert_eq!(parse_position_reply(3, &[]), Err(ReplyError::Silent));
    let mut long = good.to_vec();
    long.push(0);
    assert_eq!(parse_position_reply(3, &long), Err(ReplyError::Unexpected));
    assert_eq!(
        parse_position_reply(3, &exception_reply(3, 2)),
        Err(ReplyError::Exception(2))
    );
    // A reply with another byte count is not a position.
    let mut six_bytes = vec![3, READ_HOLDING_REGISTERS, 6, 0, 0, 0, 0];
    six_bytes.extend_from_slice(&crc16(&six_bytes).to_le_bytes());
    assert_eq!(
        parse_position_reply(3, &six_bytes),
        Err(ReplyError::Unexpected)
    );
}

#[test]
fn timing_follows_the_modbus_rules() {
    let fast = BusTiming::at(115_200, 20_000);
    assert_eq!(fast.char_us, 96);
    assert_eq!(fast.silent_us, 1_750);
    let slow = BusTiming::at(9_600, 20_000);
    assert_eq!(slow.char_us, 1_146);
    assert_eq!(slow.silent_us, 4_011);
    // 8 dead encoders at the defaults: about half a second, bounded (the trajectory
    // task yields while it waits, so the watchdog is fed meanwhile).
    assert_eq!(
        EncoderConfig::DEFAULT.worst_read_us(8),
        3 * 8 * (768 + 20_000 + 1_750)
    );
}

#[test]
fn counts_scale_to_steps() {
    let e = EncoderJoint {
        address: 1,
        counts_per_rev: 4096,
        steps_per_rev: 3200,
        zero_counts: 1000,
        reversed: false,
    };
    assert_eq!(e.steps(1000), 0);
    assert_eq!(e.steps(1000 + 4096), 3200);
    assert_eq!(e.steps(1000 - 4096 * 10), -32_000);
    assert_eq!(e.steps(1000 + 2), 2); // 1.5625 rounds to 2
    let r = EncoderJoint {
        reversed: true,
        ..e
    };
    assert_eq!(r.steps(1000 + 4096), -3200);
    assert_eq!(EncoderJoint::in_steps(1).steps(i32::MIN), i32::MIN);
    assert_eq!(EncoderJoint::in_steps(1).steps(i32::MAX), i32::MAX);
    // Half a step rounds away from zero, both ways.
    let half = EncoderJoint {
        counts_per_rev: 2,
        steps_per_rev: 1,
        zero_counts: 0,
        ..e
    };
    assert_eq!(half.steps(1), 1);
    assert_eq!(half.steps(-1), -1);
    assert_eq!(half.steps(3), 2);
    // Huge ratios saturate instead of wrapping.
    let huge = EncoderJoint {
        counts_per_rev: 1,
        steps_per_rev: u32::MAX,
        zero_counts: 0,
        ..e
    };
    assert_eq!(huge.steps(i32::MAX), i32::MAX);
    assert_eq!(huge.steps(i32::MIN), i32::MIN);
}

/// What the fake bus does with each request.
#[derive(Clone, Copy, Debug)]
enum Behaviour {
    Answer(i32),
    Silent,
    CorruptCrc(i32),
    Exception(u8),
}

/// Encoders on a simulated bus; records every transaction and the waiting it did.
struct FakeBus {
    /// Per address: what the next requests get (the last one repeats).
    script: std::collections::HashMap<u8, VecDeque<Behaviour>>,
    pending: Vec<u8>,
    sent: Vec<[u8; REQUEST_LEN]>,
    waited_us: u64,
}

impl FakeBus {
    fn new(script: &[(u8, &[Behaviour])]) -> Self {
        FakeBus {
            script: script
                .iter()
                .map(|(a, b)| (*a, b.iter().copied().collect()))
                .collect(),
            pending: Vec::new(),
            sent: Vec::new(),
            waited_us: 0,
        }
    }
}

impl EncoderBus for FakeBus {
    async fn send(&mut self, frame: &[u8]) -> Result<(), ()> {
        self.sent.push(frame.try_into().unwrap());
        let (address, _) = parse_position_request(frame).unwrap();
        let Some(queue) = self.script.get_mut(&address) else {
            return Ok(());
        };
        let behaviour = if queue.len() > 1 {
            queue.pop_front().unwrap()
        } else {
            queue[0]
        };
        self.pending = match behaviour {
            Behaviour::Answer(c) => position_reply(address, c).to_vec(),
            Behaviour::Silent => Vec::new(),
            Behaviour::CorruptCrc(c) => {
                let mut r = position_reply(address, c);
                r[8] ^= 0xFF;
                r.to_vec()
            }
            Behaviour::Exception(code) => exception_reply(address, code).to_vec(),
        };
        Ok(())
    }

    async fn receive(&mut self, buf: &mut [u8], first_byte_us: u32, silent_us: u32) -> usize {
        let reply = core::mem::take(&mut self.pending);
        if reply.is_empty() {
            self.waited_us += u64::from(first_byte_us);
            return 0;
        }
        self.waited_us += u64::from(silent_us);
        let n = reply.len().min(buf.len());
        buf[..n].copy_from_slice(&reply[..n]);
        n
    }

    async fn pause(&mut self, us: u32) {
        self.waited_us += u64::from(us);
    }
}

#[test]
fn every_joint_in_use_is_read_in_steps() {
    let mut bus = FakeBus::new(&[
        (1, &[Behaviour::Answer(100)]),
        (2, &[Behaviour::Answer(-200)]),
        (3, &[Behaviour::Answer(300)]),
    ]);
    let read = block_on(read_positions(&mut bus, &EncoderConfig::DEFAULT, 3));
    assert_eq!(read, Ok([100, -200, 300, 0, 0, 0, 0, 0]));
    assert_eq!(bus.sent.len(), 3, "joints not in use are not asked");
}

#[test]
fn a_silent_encoder_times_out_after_every_attempt_and_names_its_joint() {
    let mut bus = FakeBus::new(&[(1, &[Behaviour::Answer(5)]), (2, &[Behaviour::Silent])]);
    let config = EncoderConfig::DEFAULT;
    let read = block_on(read_positions(&mut bus, &config, 3));
    assert_eq!(
        read,
        Err(EncoderFault {
            joint: 1,
            kind: EncoderFaultKind::NoAnswer
        })
    );
    assert_eq!(bus.sent.len(), 1 + usize::from(config.attempts));
    // Each attempt waited the full response timeout and a silent interval.
    let per_attempt = u64::from(config.timing.response_timeout_us + config.timing.silent_us);
    assert_eq!(
        bus.waited_us,
        u64::from(config.timing.silent_us) + 3 * per_attempt
    );
}

#[test]
fn a_corrupted_reply_is_retried_and_the_retry_counts() {
    let mut bus = FakeBus::new(&[(1, &[Behaviour::CorruptCrc(5), Behaviour::Answer(7)])]);
    let read = block_on(read_positions(&mut bus, &EncoderConfig::DEFAULT, 1));
    assert_eq!(read.map(|p| p[0]), Ok(7));
    assert_eq!(bus.sent.len(), 2);
}

#[test]
fn persistent_crc_errors_and_exceptions_are_reported_as_such() {
    let mut bus = FakeBus::new(&[(1, &[Behaviour::CorruptCrc(5)])]);
    let read = block_on(read_positions(&mut bus, &EncoderConfig::DEFAULT, 1));
    assert_eq!(read.unwrap_err().kind, EncoderFaultKind::BadCrc);
    let mut bus = FakeBus::new(&[(1, &[Behaviour::Exception(2)])]);
    let read = block_on(read_positions(&mut bus, &EncoderConfig::DEFAULT, 1));
    assert_eq!(read.unwrap_err().kind, EncoderFaultKind::Exception(2));
    assert_eq!(bus.sent.len(), 1, "an exception is not retried");
}

#[test]
fn probe_asks_once_and_tells_fitted_from_absent() {
    let all = [
        (1, &[Behaviour::Answer(1)][..]),
        (2, &[Behaviour::Answer(2)][..]),
    ];
    let mut bus = FakeBus::new(&all);
    assert!(block_on(probe(&mut bus, &EncoderConfig::DEFAULT, 2)));
    assert_eq!(bus.sent.len(), 2);
    // Joint 0 answers, joint 1 is dead: fitted (RETURN will refuse, naming joint 1).
    let mut bus = FakeBus::new(&[(1, &[Behaviour::Answer(1)])]);
    assert!(block_on(probe(&mut bus, &EncoderConfig::DEFAULT, 6)));
    assert_eq!(bus.sent.len(), 2, "one attempt per joint");
    // Joint 0 answers with an error: a device is there.
    let mut bus = FakeBus::new(&[(1, &[Behaviour::CorruptCrc(1)])]);
    assert!(block_on(probe(&mut bus, &EncoderConfig::DEFAULT, 6)));
    // Nobody: not fitted, after one request.
    let mut bus = FakeBus::new(&[]);
    assert!(!block_on(probe(&mut bus, &EncoderConfig::DEFAULT, 6)));
    assert_eq!(bus.sent.len(), 1);
}

proptest! {
    #[test]
    fn any_position_round_trips(address in 1u8..=247, counts in any::<i32>()) {
        prop_assert_eq!(parse_position_reply(address, &position_reply(address, counts)), Ok(counts));
    }

    #[test]
    fn any_single_bit_error_is_caught(counts in any::<i32>(), bit in 0usize..72) {
        let mut reply = position_reply(1, counts);
        reply[bit / 8] ^= 1 << (bit % 8);
        prop_assert!(parse_position_reply(1, &reply).is_err());
    }

    #[test]
    fn garbage_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..20)) {
        let _ = parse_position_reply(1, &bytes);
        let _ = parse_position_request(&bytes);
    }
}
