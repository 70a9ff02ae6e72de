//! Absolute multi-turn encoders on an RS-485 bus, read with Modbus RTU (the vendor's
//! variant of this controller did the same). One encoder per joint, each at its own
//! Modbus address; the position is a signed 32-bit count in two holding registers
//! (high word first), as most RS-485 multi-turn encoders (e.g. the BRT38-R0M series and
//! its many clones) expose it.
//!
//! A read of joint `j` is one transaction:
//!
//! ```text
//! request  addr 03 reg_hi reg_lo 00 02 crc_lo crc_hi          (8 bytes)
//! reply    addr 03 04 p3 p2 p1 p0 crc_lo crc_hi               (9 bytes, p3 = MSB)
//! error    addr 83 code crc_lo crc_hi                         (5 bytes, Modbus exception)
//! ```
//!
//! Every reply is checked: its CRC-16/MODBUS, address, function and byte count. No reply
//! within the response timeout, a bad CRC or a malformed reply is retried
//! ([`EncoderConfig::attempts`] in all), after the bus's silent interval; a joint that
//! still has no good answer fails the whole read with an [`EncoderFault`] naming it, and
//! RETURN then ends in STOPPED without moving (see arm-core's `Controller::fail_return`).

use arm_core::hw::{EncoderFault, EncoderFaultKind};
use protocol::MAX_JOINTS;

/// Modbus function "read holding registers".
pub const READ_HOLDING_REGISTERS: u8 = 0x03;
/// Bit set in the function code of an exception reply.
pub const EXCEPTION_BIT: u8 = 0x80;
/// Bytes of a position request.
pub const REQUEST_LEN: usize = 8;
/// Bytes of a position reply.
pub const POSITION_REPLY_LEN: usize = 9;
/// Bytes of an exception reply.
pub const EXCEPTION_REPLY_LEN: usize = 5;
/// The longest reply read: a position reply (longer answers are not ours).
pub const MAX_REPLY_LEN: usize = POSITION_REPLY_LEN;

/// Bitwise, no table: a few dozen bytes per frame at most, and 512 bytes less flash.
const MODBUS_CRC: crc::Crc<u16, crc::NoTable> =
    crc::Crc::<u16, crc::NoTable>::new(&crc::CRC_16_MODBUS);

/// CRC-16/MODBUS of `bytes` (sent low byte first).
pub fn crc16(bytes: &[u8]) -> u16 {
    MODBUS_CRC.checksum(bytes)
}

/// The request for the position registers of the encoder at `address`.
pub fn position_request(address: u8, register: u16) -> [u8; REQUEST_LEN] {
    let [reg_hi, reg_lo] = register.to_be_bytes();
    let mut frame = [address, READ_HOLDING_REGISTERS, reg_hi, reg_lo, 0, 2, 0, 0];
    let [crc_lo, crc_hi] = crc16(&frame[..6]).to_le_bytes();
    frame[6] = crc_lo;
    frame[7] = crc_hi;
    frame
}

/// The reply an encoder at `address` sends with its position `counts`.
pub fn position_reply(address: u8, counts: i32) -> [u8; POSITION_REPLY_LEN] {
    let [p3, p2, p1, p0] = counts.to_be_bytes();
    let mut frame = [address, READ_HOLDING_REGISTERS, 4, p3, p2, p1, p0, 0, 0];
    let [crc_lo, crc_hi] = crc16(&frame[..7]).to_le_bytes();
    frame[7] = crc_lo;
    frame[8] = crc_hi;
    frame
}

/// The exception reply an encoder at `address` sends for `code`.
pub fn exception_reply(address: u8, code: u8) -> [u8; EXCEPTION_REPLY_LEN] {
    let mut frame = [address, READ_HOLDING_REGISTERS | EXCEPTION_BIT, code, 0, 0];
    let [crc_lo, crc_hi] = crc16(&frame[..3]).to_le_bytes();
    frame[3] = crc_lo;
    frame[4] = crc_hi;
    frame
}

/// A position request as an encoder receives it: (address, register) if the frame is
/// one (CRC checked). For the simulated encoder.
pub fn parse_position_request(frame: &[u8]) -> Option<(u8, u16)> {
    let (body, crc) = frame.split_last_chunk::<2>()?;
    let [address, function, reg_hi, reg_lo, 0, 2] = *body else {
        return None;
    };
    let crc_ok = crc16(body) == u16::from_le_bytes(*crc);
    (crc_ok && function == READ_HOLDING_REGISTERS)
        .then(|| (address, u16::from_be_bytes([reg_hi, reg_lo])))
}

/// What is wrong with a reply.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ReplyError {
    /// Nothing arrived.
    Silent,
    /// Fewer bytes than a reply has (cut off, or noise).
    Short,
    /// The CRC does not match.
    BadCrc,
    /// A well-formed frame, but from another address, for another function or with a
    /// wrong byte count.
    Unexpected,
    /// The encoder answered with a Modbus exception.
    Exception(u8),
}

impl ReplyError {
    /// The fault reported when the last attempt ended with this error.
    pub fn fault_kind(self) -> EncoderFaultKind {
        match self {
            ReplyError::Silent => EncoderFaultKind::NoAnswer,
            ReplyError::BadCrc => EncoderFaultKind::BadCrc,
            ReplyError::Short | ReplyError::Unexpected => EncoderFaultKind::BadReply,
            ReplyError::Exception(code) => EncoderFaultKind::Exception(code),
        }
    }
}

/// The position in a reply from `address`.
pub fn parse_position_reply(address: u8, reply: &[u8]) -> Result<i32, ReplyError> {
    if reply.is_empty() {
        return Err(ReplyError::Silent);
    }
    let exception = reply.get(1).is_some_and(|f| f & EXCEPTION_BIT != 0);
    let len = if exception {
        EXCEPTION_REPLY_LEN
    } else {
        POSITION_REPLY_LEN
    };
    let Some(frame) = reply.get(..len) else {
        return Err(ReplyError::Short);
    };
    if reply.len() != len {
        return Err(ReplyError::Unexpected);
    }
    let Some((body, crc)) = frame.split_last_chunk::<2>() else {
        return Err(ReplyError::Short);
    };
    if crc16(body) != u16::from_le_bytes(*crc) {
        return Err(ReplyError::BadCrc);
    }
    match *body {
        [a, f, code] if a == address && f == READ_HOLDING_REGISTERS | EXCEPTION_BIT => {
            Err(ReplyError::Exception(code))
        }
        [a, READ_HOLDING_REGISTERS, 4, p3, p2, p1, p0] if a == address => {
            Ok(i32::from_be_bytes([p3, p2, p1, p0]))
        }
        _ => Err(ReplyError::Unexpected),
    }
}

/// Timing of the bus, from its baud rate (Modbus over serial line, section 2.5.1.1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BusTiming {
    /// Time on the line of one character (11 bits: start, 8 data, parity or a second
    /// stop, stop), microseconds.
    pub char_us: u32,
    /// The silent interval that ends a frame (3.5 characters; 1750 us above 19200 baud).
    pub silent_us: u32,
    /// How long to wait for the first byte of a reply after the request was sent.
    pub response_timeout_us: u32,
}

impl BusTiming {
    /// The timing at `baud` with a response timeout of `response_timeout_us`.
    pub const fn at(baud: u32, response_timeout_us: u32) -> Self {
        let char_us = 11_000_000u32.div_ceil(baud);
        let silent_us = if baud > 19_200 {
            1_750
        } else {
            (7 * char_us).div_ceil(2u32)
        };
        BusTiming {
            char_us,
            silent_us,
            response_timeout_us,
        }
    }

    /// Line time of `bytes` characters, microseconds.
    #[allow(
        clippy::cast_possible_truncation,
        reason = "a Modbus frame's byte count, 256 at most"
    )]
    pub const fn frame_us(&self, bytes: usize) -> u32 {
        self.char_us * bytes as u32
    }
}

/// One joint's encoder.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EncoderJoint {
    /// Its Modbus address (1..=247).
    pub address: u8,
    /// Encoder counts per motor revolution (after any gearbox between them: counts per
    /// `steps_per_rev` steps).
    pub counts_per_rev: u32,
    /// Motor steps per revolution, microsteps included.
    pub steps_per_rev: u32,
    /// The count at the joint's zero.
    pub zero_counts: i32,
    /// Whether the encoder counts up when the joint steps negative.
    pub reversed: bool,
}

impl EncoderJoint {
    /// An encoder at `address` that counts in steps, zero at zero.
    pub const fn in_steps(address: u8) -> Self {
        EncoderJoint {
            address,
            counts_per_rev: 1,
            steps_per_rev: 1,
            zero_counts: 0,
            reversed: false,
        }
    }

    /// The joint position in steps for `counts` (rounded to the nearest step, saturated).
    /// 64-bit arithmetic (the product saturates rather than overflows): 128-bit division
    /// would cost a kilobyte of flash for ratios no encoder needs.
    pub fn steps(&self, counts: i32) -> i32 {
        let from_zero = i64::from(counts) - i64::from(self.zero_counts);
        let signed = if self.reversed { -from_zero } else { from_zero };
        let num = signed.saturating_mul(i64::from(self.steps_per_rev));
        let den = i64::from(self.counts_per_rev.max(1));
        // Round half away from zero: (|num| + den / 2) / den, with the sign of num.
        let magnitude = num.unsigned_abs().saturating_add(den as u64 / 2) / den as u64;
        let steps = i64::try_from(magnitude).unwrap_or(i64::MAX);
        let steps = if num < 0 { -steps } else { steps };
        i32::try_from(steps).unwrap_or(if steps < 0 { i32::MIN } else { i32::MAX })
    }
}

/// The encoders of every joint.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct EncoderConfig {
    /// Joint j's encoder.
    pub joints: [EncoderJoint; MAX_JOINTS],
    /// First of the two position registers.
    pub register: u16,
    /// Transactions per joint before it is declared faulty (1 = no retry).
    pub attempts: u8,
    /// The bus timing.
    pub timing: BusTiming,
}

/// Baud rate of the encoder bus: the common factory default of RS-485 encoders.
pub const DEFAULT_BAUD: u32 = 115_200;
/// Response timeout: encoders answer within 1-5 ms; 20 ms leaves margin for slow ones
/// and still bounds a read of 8 dead encoders (3 attempts each) to about half a second.
pub const DEFAULT_RESPONSE_TIMEOUT_US: u32 = 20_000;

impl EncoderConfig {
    /// Joint j at address j + 1, counting in steps, position in registers 0-1, 3
    /// attempts, 115200 baud.
    pub const DEFAULT: EncoderConfig = EncoderConfig {
        joints: [
            EncoderJoint::in_steps(1),
            EncoderJoint::in_steps(2),
            EncoderJoint::in_steps(3),
            EncoderJoint::in_steps(4),
            EncoderJoint::in_steps(5),
            EncoderJoint::in_steps(6),
            EncoderJoint::in_steps(7),
            EncoderJoint::in_steps(8),
        ],
        register: 0,
        attempts: 3,
        timing: BusTiming::at(DEFAULT_BAUD, DEFAULT_RESPONSE_TIMEOUT_US),
    };

    /// The longest a read of `joints` encoders can take, microseconds (all silent, every
    /// attempt timing out): for documentation and the watchdog budget.
    pub const fn worst_read_us(&self, joints: u8) -> u32 {
        let per_attempt = self.timing.frame_us(REQUEST_LEN)
            + self.timing.response_timeout_us
            + self.timing.silent_us;
        per_attempt * self.attempts as u32 * joints as u32
    }
}

/// The RS-485 bus as the reader uses it.
pub trait EncoderBus {
    /// Transmits `frame` (driving the transceiver's DE line for exactly its duration) and
    /// waits until its last bit is on the line.
    fn send(&mut self, frame: &[u8]) -> impl Future<Output = Result<(), ()>>;
    /// Receives one reply into `buf`: waits up to `first_byte_timeout_us` for its first
    /// byte, then takes bytes until the line is silent for `silent_us` or `buf` is full.
    /// Returns the bytes received (0: nothing arrived in time).
    fn receive(
        &mut self,
        buf: &mut [u8],
        first_byte_timeout_us: u32,
        silent_us: u32,
    ) -> impl Future<Output = usize>;
    /// Keeps the bus silent for `us` microseconds (between transactions).
    fn pause(&mut self, us: u32) -> impl Future<Output = ()>;
}

use core::future::Future;

/// The raw count of one encoder, with retries.
pub async fn read_counts<B: EncoderBus>(
    bus: &mut B,
    config: &EncoderConfig,
    address: u8,
) -> Result<i32, ReplyError> {
    let request = position_request(address, config.register);
    let mut last = ReplyError::Silent;
    for _ in 0..config.attempts.max(1) {
        let mut reply = [0u8; MAX_REPLY_LEN + 1];
        let n = if bus.send(&request).await.is_ok() {
            bus.receive(
                &mut reply,
                config.timing.response_timeout_us,
                config.timing.silent_us,
            )
            .await
        } else {
            0
        };
        match parse_position_reply(address, reply.get(..n).unwrap_or_default()) {
            Ok(counts) => return Ok(counts),
            // An exception is the encoder's considered answer: retrying will not change it.
            Err(e @ ReplyError::Exception(_)) => return Err(e),
            Err(e) => last = e,
        }
        // Let a late or garbled reply finish before the next request.
        bus.pause(config.timing.silent_us).await;
    }
    Err(last)
}

/// The positions in steps of joints `0..joints` (the others 0), or the first joint that
/// did not answer properly.
pub async fn read_positions<B: EncoderBus>(
    bus: &mut B,
    config: &EncoderConfig,
    joints: u8,
) -> Result<[i32; MAX_JOINTS], EncoderFault> {
    let mut positions = [0i32; MAX_JOINTS];
    for (j, (position, encoder)) in positions
        .iter_mut()
        .zip(config.joints.iter())
        .enumerate()
        .take(usize::from(joints).min(MAX_JOINTS))
    {
        match read_counts(bus, config, encoder.address).await {
            Ok(counts) => *position = encoder.steps(counts),
            Err(e) => {
                return Err(EncoderFault {
                    // j < MAX_JOINTS.
                    joint: u8::try_from(j).unwrap_or(u8::MAX),
                    kind: e.fault_kind(),
                });
            }
        }
    }
    Ok(positions)
}

/// Whether encoders are fitted at all: one read of joints `0..joints` with a single
/// attempt each. Encoders are fitted if it succeeds, or if it fails anywhere but with
/// silence on joint 0 (something answered: joint 0's encoder, or the read got past it).
/// A board without encoders then runs RETURN on the step count; with encoders, a later
/// failure refuses RETURN instead. (The same read as RETURN's: one copy of the code.)
pub async fn probe<B: EncoderBus>(bus: &mut B, config: &EncoderConfig, joints: u8) -> bool {
    let once = EncoderConfig {
        attempts: 1,
        ..*config
    };
    match read_positions(bus, &once, joints).await {
        Ok(_) => true,
        Err(fault) => fault.joint > 0 || fault.kind != EncoderFaultKind::NoAnswer,
    }
}

#[cfg(test)]
mod tests;
