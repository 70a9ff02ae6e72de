//! Optional authentication (docs/PROTOCOL.md section 13, issue 21): the AUTH envelope,
//! its keyed BLAKE2s-128 MAC, the HELLO handshake's reply and the replay window.
//!
//! An envelope is an ordinary frame (tag 0x50, CRC-8 last) whose data is a session id, a
//! counter, a whole inner frame (seq, tag, data, CRC) and a 16-byte MAC:
//!
//! ```text
//! | seq | 0x50 | session u32 | counter u64 | inner frame | mac [16] | crc |
//! ```
//!
//! The MAC is BLAKE2s keyed with the 32-byte key, 16 bytes of output, personalised with
//! the direction (a host's frame can never pass for the controller's), over the
//! controller's boot epoch (8 bytes, little-endian; not sent: both ends know it from
//! HELLO) followed by every byte of the envelope before the MAC. Keyed BLAKE2s is a MAC by
//! design (RFC 7693 section 2.9), 32-bit native (fast on a Cortex-M7 without crypto
//! hardware) and needs no HMAC double pass.

use blake2::Blake2sMac;
use blake2::digest::consts::U16;
use blake2::digest::{FixedOutput, Update};

use crate::codec::{Writer, u8_at, u32_le, u64_le};
use crate::codes::Tag;
use crate::error::EncodeError;
use crate::error::{DecodeError, DecodeErrorKind, ExpectedLen};
use crate::frame::{Frame, crc8, open};
use crate::{FRAME_OVERHEAD, MAX_DATAGRAM};

/// Bytes of a key.
pub const KEY_LEN: usize = 32;
/// Bytes of a MAC: BLAKE2s output truncated by its parameter block to 128 bits (forging
/// one takes 2^128 tries; the controller answers at most a few thousand a second).
pub const MAC_LEN: usize = 16;
/// Bytes of a HELLO's host nonce.
pub const NONCE_LEN: usize = 16;
/// Bytes of the envelope before the inner frame: seq, tag, session, counter.
pub const ENVELOPE_HEADER: usize = 2 + 4 + 8;
/// Bytes an envelope adds to its inner frame: header, MAC, CRC.
pub const ENVELOPE_OVERHEAD: usize = ENVELOPE_HEADER + MAC_LEN + 1;
/// Largest inner frame: a datagram less the envelope. A 12-point PENDING (1395 bytes)
/// fits.
pub const MAX_INNER: usize = MAX_DATAGRAM - ENVELOPE_OVERHEAD;
/// Bytes of HELLO_REPLY data: the host's nonce, the epoch, the session.
pub const HELLO_REPLY_LEN: usize = NONCE_LEN + 8 + 4;
/// Counters a session accepts out of order below the highest seen: twice the host
/// window (32), so that a window of frames overtaking one another all pass, once each.
pub const REPLAY_WINDOW: u64 = 64;

/// A shared key. Its `Debug` and `defmt` forms never show the bytes (settings are logged).
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct AuthKey(pub [u8; KEY_LEN]);

impl core::fmt::Debug for AuthKey {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("AuthKey(..)")
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for AuthKey {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "AuthKey(..)")
    }
}

#[cfg(feature = "serde")]
impl serde::Serialize for AuthKey {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str("(key)")
    }
}

/// Which way a frame travels: part of the MAC, so a frame of one direction never
/// verifies in the other.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Direction {
    /// Host to controller.
    ToController,
    /// Controller to host.
    ToHost,
}

impl Direction {
    /// BLAKE2s personalisation (8 bytes).
    const fn persona(self) -> &'static [u8; 8] {
        match self {
            Direction::ToController => b"armH2C01",
            Direction::ToHost => b"armC2H01",
        }
    }
}

/// The MAC of `bytes` (an envelope up to its MAC) under `key` for `direction` and `epoch`.
pub fn mac(key: &AuthKey, direction: Direction, epoch: u64, bytes: &[u8]) -> [u8; MAC_LEN] {
    // A 32-byte key and an 8-byte persona are within BLAKE2s's limits: never an error.
    let Ok(mut m) =
        Blake2sMac::<U16>::new_with_salt_and_personal(Some(&key.0), &[], direction.persona())
    else {
        return [0; MAC_LEN];
    };
    m.update(&epoch.to_le_bytes());
    m.update(bytes);
    m.finalize_fixed().into()
}

/// Compares two MACs in time independent of where they differ.
fn same_mac(a: &[u8; MAC_LEN], b: &[u8]) -> bool {
    b.len() == MAC_LEN && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// Why an envelope was not opened. Each maps to a status code (see [`EnvelopeError::status`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EnvelopeError {
    /// Not tag 0x50, or too short to hold a header, an inner frame of 3 bytes and a MAC.
    Malformed,
    /// The outer CRC does not match.
    BadCrc,
    /// The inner frame's own CRC does not match (the sender's encoder is wrong).
    BadInnerCrc,
}

/// An envelope's fields, its CRC checked, its MAC not yet.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Envelope<'a> {
    /// The outer seq (the inner frame's, copied).
    pub seq: u8,
    /// The session the sender holds (HELLO gave it).
    pub session: u32,
    /// The sender's counter: one more for every envelope it sends in the session.
    pub counter: u64,
    /// The inner frame, whole (seq, tag, data, CRC).
    pub inner: &'a [u8],
    /// What the MAC covers: every byte before it.
    signed: &'a [u8],
    /// The MAC as received.
    mac: &'a [u8],
}

impl<'a> Envelope<'a> {
    /// Splits an envelope and checks both CRCs. Never panics.
    pub fn open(bytes: &'a [u8]) -> Result<Envelope<'a>, EnvelopeError> {
        if bytes.len() < ENVELOPE_OVERHEAD + FRAME_OVERHEAD
            || bytes.get(1) != Some(&(Tag::Auth as u8))
        {
            return Err(EnvelopeError::Malformed);
        }
        let Some((&crc, body)) = bytes.split_last() else {
            return Err(EnvelopeError::Malformed);
        };
        if crc8(body) != crc {
            return Err(EnvelopeError::BadCrc);
        }
        let (signed, mac) = body.split_at(body.len() - MAC_LEN);
        let inner = signed.get(ENVELOPE_HEADER..).unwrap_or_default();
        match inner.split_last() {
            Some((&c, b)) if crc8(b) == c => {}
            _ => return Err(EnvelopeError::BadInnerCrc),
        }
        Ok(Envelope {
            seq: bytes.first().copied().unwrap_or(0),
            session: u32_le(signed, 2),
            counter: u64_le(signed, 6),
            inner,
            signed,
            mac,
        })
    }

    /// Whether its MAC is right for `key`, `direction` and `epoch`.
    pub fn verify(&self, key: &AuthKey, direction: Direction, epoch: u64) -> bool {
        same_mac(&mac(key, direction, epoch, self.signed), self.mac)
    }
}

/// Wraps `inner` (a whole frame) in an envelope into `buf`; returns its length.
pub fn seal(
    key: &AuthKey,
    direction: Direction,
    epoch: u64,
    session: u32,
    counter: u64,
    inner: &[u8],
    buf: &mut [u8],
) -> Result<usize, EncodeError> {
    let needed = inner.len() + ENVELOPE_OVERHEAD;
    if inner.len() < FRAME_OVERHEAD || needed > MAX_DATAGRAM {
        return Err(EncodeError::InvalidContent);
    }
    let available = buf.len();
    let Some(frame) = buf.get_mut(..needed) else {
        return Err(EncodeError::BufferTooSmall { needed, available });
    };
    let signed_len = ENVELOPE_HEADER + inner.len();
    let mut w = Writer { buf: frame };
    w.u8(0, u8_at(inner, 0));
    w.u8(1, Tag::Auth as u8);
    w.u32(2, session);
    w.put(6, &counter.to_le_bytes());
    w.put(ENVELOPE_HEADER, inner);
    let m = mac(
        key,
        direction,
        epoch,
        w.buf.get(..signed_len).unwrap_or_default(),
    );
    w.put(signed_len, &m);
    let crc = crc8(w.buf.get(..needed - 1).unwrap_or_default());
    w.u8(needed - 1, crc);
    Ok(needed)
}

/// What HELLO_REPLY (tag 0x53, only ever inside an envelope) tells a host.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct HelloReply {
    /// The HELLO's nonce, echoed: the reply is fresh (no one could have made it earlier).
    pub nonce: [u8; NONCE_LEN],
    /// The controller's boot epoch: part of every MAC until the next reset.
    pub epoch: u64,
    /// The session granted: the host's envelopes carry it, counting from 1.
    pub session: u32,
}

impl HelloReply {
    /// Its data bytes.
    pub fn to_bytes(&self) -> [u8; HELLO_REPLY_LEN] {
        let mut b = [0; HELLO_REPLY_LEN];
        let mut w = Writer { buf: &mut b };
        w.put(0, &self.nonce);
        w.put(NONCE_LEN, &self.epoch.to_le_bytes());
        w.u32(NONCE_LEN + 8, self.session);
        b
    }

    /// Writes the HELLO_REPLY frame (the HELLO's seq) into `buf`; returns its length.
    pub fn encode(&self, seq: u8, buf: &mut [u8]) -> Result<usize, EncodeError> {
        crate::frame::seal(seq, Tag::HelloReply, HELLO_REPLY_LEN, buf, |w| {
            w.put(0, &self.to_bytes())
        })
    }

    /// Decodes a HELLO_REPLY frame (an envelope's inner frame). Never panics.
    pub fn decode(bytes: &[u8]) -> Result<Frame<HelloReply>, DecodeError> {
        let (seq, tag, data) = open(bytes)?;
        let err = |kind| DecodeError { seq, tag, kind };
        if tag != Tag::HelloReply as u8 {
            return Err(err(DecodeErrorKind::UnknownTag));
        }
        match HelloReply::read(data) {
            Some(body) => Ok(Frame { seq, body }),
            None => Err(err(DecodeErrorKind::BadLength {
                expected: ExpectedLen::Exactly(HELLO_REPLY_LEN),
                found: data.len(),
            })),
        }
    }

    /// Reads its data bytes (exactly [`HELLO_REPLY_LEN`]).
    pub fn read(data: &[u8]) -> Option<HelloReply> {
        if data.len() != HELLO_REPLY_LEN {
            return None;
        }
        Some(HelloReply {
            nonce: data.get(..NONCE_LEN)?.try_into().ok()?,
            epoch: u64_le(data, NONCE_LEN),
            session: u32_le(data, NONCE_LEN + 8),
        })
    }
}

/// The counters a session has accepted: the highest, and which of the
/// [`REPLAY_WINDOW`] below it (an IPsec-style window). Each counter passes once.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ReplayWindow {
    highest: u64,
    /// Bit i: `highest - i` was accepted.
    seen: u64,
}

impl ReplayWindow {
    /// Nothing accepted yet (counters start at 1).
    pub const fn new() -> Self {
        ReplayWindow {
            highest: 0,
            seen: 0,
        }
    }

    /// Whether `counter` would pass: never seen, and not too old.
    pub fn is_fresh(&self, counter: u64) -> bool {
        if counter == 0 {
            return false;
        }
        if counter > self.highest {
            return true;
        }
        let age = self.highest - counter;
        age < REPLAY_WINDOW && self.seen & (1 << age) == 0
    }

    /// Marks `counter` accepted if it is fresh; returns whether it was.
    pub fn accept(&mut self, counter: u64) -> bool {
        if !self.is_fresh(counter) {
            return false;
        }
        if counter > self.highest {
            let shift = counter - self.highest;
            self.seen = if shift >= REPLAY_WINDOW {
                0
            } else {
                self.seen << shift
            };
            self.seen |= 1;
            self.highest = counter;
        } else {
            self.seen |= 1 << (self.highest - counter);
        }
        true
    }

    /// The highest counter accepted (0: none).
    pub fn highest(&self) -> u64 {
        self.highest
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const KEY: AuthKey = AuthKey([7; KEY_LEN]);

    #[test]
    fn envelope_round_trips_and_a_changed_byte_fails() {
        let inner = [5u8, 0x15, crc8(&[5, 0x15])];
        let mut buf = [0u8; 64];
        let n = seal(&KEY, Direction::ToController, 9, 3, 42, &inner, &mut buf).unwrap();
        assert_eq!(n, inner.len() + ENVELOPE_OVERHEAD);
        let env = Envelope::open(&buf[..n]).unwrap();
        assert_eq!((env.seq, env.session, env.counter), (5, 3, 42));
        assert_eq!(env.inner, &inner);
        assert!(env.verify(&KEY, Direction::ToController, 9));
        assert!(!env.verify(&KEY, Direction::ToHost, 9));
        assert!(!env.verify(&KEY, Direction::ToController, 10));
        assert!(!env.verify(&AuthKey([8; KEY_LEN]), Direction::ToController, 9));
        // The counter changed, CRC recomputed: the MAC no longer matches.
        buf[6] ^= 1;
        buf[n - 1] = crc8(&buf[..n - 1]);
        assert!(
            !Envelope::open(&buf[..n])
                .unwrap()
                .verify(&KEY, Direction::ToController, 9)
        );
        assert_eq!(Envelope::open(&buf[..5]), Err(EnvelopeError::Malformed));
    }

    #[test]
    fn replay_window_takes_each_counter_once() {
        let mut w = ReplayWindow::new();
        assert!(!w.accept(0));
        assert!(w.accept(1));
        assert!(!w.accept(1));
        assert!(w.accept(5));
        assert!(w.accept(3));
        assert!(!w.accept(3));
        assert!(w.accept(100));
        assert!(!w.accept(5), "older than the window");
        assert!(w.accept(99));
        assert!(w.accept(37));
        assert!(!w.accept(36));
    }

    #[test]
    fn hello_reply_round_trips() {
        let r = HelloReply {
            nonce: [1; NONCE_LEN],
            epoch: 0x0102_0304_0506_0708,
            session: 77,
        };
        assert_eq!(HelloReply::read(&r.to_bytes()), Some(r));
    }
}
