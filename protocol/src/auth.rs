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

/// BLAKE2s's initial vector (RFC 7693 section 2.6).
const IV: [u32; 8] = [
    0x6A09_E667,
    0xBB67_AE85,
    0x3C6E_F372,
    0xA54F_F53A,
    0x510E_527F,
    0x9B05_688C,
    0x1F83_D9AB,
    0x5BE0_CD19,
];

/// BLAKE2s's compression function F (RFC 7693 section 3.2) of one 64-byte block.
///
/// Written here rather than taken from the `blake2` crate, which the tests compare it
/// with: the controller runs it for every byte of every envelope, and this plain form
/// (the state in 16 locals, the rounds unrolled) takes about a third fewer Cortex-M7
/// instructions than the crate's generic one (scripts/auth-cost).
// Indices are constants below 16 and 4-byte chunks' (0..4); `t` is split in halves.
#[allow(clippy::indexing_slicing, clippy::cast_possible_truncation)]
// One copy of its ~5 KB of unrolled code (called per block: the call costs nothing beside
// the block's ~1,700 instructions).
#[inline(never)]
fn compress(h: &mut [u32; 8], block: &[u8; 64], t: u64, last: bool) {
    let mut m = [0u32; 16];
    for (w, b) in m.iter_mut().zip(block.chunks_exact(4)) {
        *w = u32::from_le_bytes([b[0], b[1], b[2], b[3]]);
    }
    let [
        mut v0,
        mut v1,
        mut v2,
        mut v3,
        mut v4,
        mut v5,
        mut v6,
        mut v7,
    ] = *h;
    let [
        mut v8,
        mut v9,
        mut v10,
        mut v11,
        mut v12,
        mut v13,
        mut v14,
        mut v15,
    ] = IV;
    v12 ^= t as u32;
    v13 ^= (t >> 32) as u32;
    if last {
        v14 = !v14;
    }
    macro_rules! g {
        ($a:ident, $b:ident, $c:ident, $d:ident, $x:expr, $y:expr) => {
            $a = $a.wrapping_add($b).wrapping_add($x);
            $d = ($d ^ $a).rotate_right(16);
            $c = $c.wrapping_add($d);
            $b = ($b ^ $c).rotate_right(12);
            $a = $a.wrapping_add($b).wrapping_add($y);
            $d = ($d ^ $a).rotate_right(8);
            $c = $c.wrapping_add($d);
            $b = ($b ^ $c).rotate_right(7);
        };
    }
    // One round with the message schedule's row (RFC 7693 section 2.7) as literals: the
    // rounds unrolled, every message word at a constant index.
    macro_rules! round {
        ($s0:literal, $s1:literal, $s2:literal, $s3:literal, $s4:literal, $s5:literal,
         $s6:literal, $s7:literal, $s8:literal, $s9:literal, $s10:literal, $s11:literal,
         $s12:literal, $s13:literal, $s14:literal, $s15:literal) => {
            g!(v0, v4, v8, v12, m[$s0], m[$s1]);
            g!(v1, v5, v9, v13, m[$s2], m[$s3]);
            g!(v2, v6, v10, v14, m[$s4], m[$s5]);
            g!(v3, v7, v11, v15, m[$s6], m[$s7]);
            g!(v0, v5, v10, v15, m[$s8], m[$s9]);
            g!(v1, v6, v11, v12, m[$s10], m[$s11]);
            g!(v2, v7, v8, v13, m[$s12], m[$s13]);
            g!(v3, v4, v9, v14, m[$s14], m[$s15]);
        };
    }
    round!(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
    round!(14, 10, 4, 8, 9, 15, 13, 6, 1, 12, 0, 2, 11, 7, 5, 3);
    round!(11, 8, 12, 0, 5, 2, 15, 13, 10, 14, 3, 6, 7, 1, 9, 4);
    round!(7, 9, 3, 1, 13, 12, 11, 14, 2, 6, 5, 10, 4, 0, 15, 8);
    round!(9, 0, 5, 7, 2, 4, 10, 15, 14, 1, 11, 12, 6, 8, 3, 13);
    round!(2, 12, 6, 10, 0, 11, 8, 3, 4, 13, 7, 5, 15, 14, 1, 9);
    round!(12, 5, 1, 15, 14, 13, 4, 10, 0, 7, 6, 3, 9, 2, 8, 11);
    round!(13, 11, 7, 14, 12, 1, 3, 9, 5, 0, 15, 4, 8, 6, 2, 10);
    round!(6, 15, 14, 9, 11, 3, 0, 8, 12, 2, 13, 7, 1, 4, 10, 5);
    round!(10, 2, 8, 4, 7, 6, 1, 5, 15, 11, 9, 14, 3, 12, 13, 0);
    let v = [
        v0 ^ v8,
        v1 ^ v9,
        v2 ^ v10,
        v3 ^ v11,
        v4 ^ v12,
        v5 ^ v13,
        v6 ^ v14,
        v7 ^ v15,
    ];
    for (h, v) in h.iter_mut().zip(v) {
        *h ^= v;
    }
}

/// A key made ready for MACs: BLAKE2s's state after the key block, for each direction.
/// Keyed BLAKE2s compresses the zero-padded key as its first block; done once here, when
/// the key is set, rather than for every frame (one compression of the 23 a 12-point
/// PENDING takes). Its `Debug` shows nothing of it.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct MacKey {
    /// The state after the key block: host to controller, controller to host.
    after_key: [[u32; 8]; 2],
}

impl core::fmt::Debug for MacKey {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str("MacKey(..)")
    }
}

#[cfg(feature = "defmt")]
impl defmt::Format for MacKey {
    fn format(&self, f: defmt::Formatter<'_>) {
        defmt::write!(f, "MacKey(..)")
    }
}

impl MacKey {
    /// Compresses `key`'s block for both directions.
    #[allow(clippy::cast_possible_truncation)] // KEY_LEN and MAC_LEN are 32 and 16
    pub fn new(key: &AuthKey) -> MacKey {
        let mut block = [0u8; 64];
        if let Some(head) = block.get_mut(..KEY_LEN) {
            head.copy_from_slice(&key.0);
        }
        let after = |direction: Direction| {
            let persona = direction.persona();
            let mut h = IV;
            // Parameter block: digest length 16, key length 32, fanout 1, depth 1; the
            // personalisation in words 6 and 7.
            h[0] ^= 0x0101_0000 | ((KEY_LEN as u32) << 8) | MAC_LEN as u32;
            h[6] ^= u32::from_le_bytes([persona[0], persona[1], persona[2], persona[3]]);
            h[7] ^= u32::from_le_bytes([persona[4], persona[5], persona[6], persona[7]]);
            compress(&mut h, &block, 64, false);
            h
        };
        MacKey {
            after_key: [after(Direction::ToController), after(Direction::ToHost)],
        }
    }

    /// The MAC of `bytes` (an envelope up to its MAC) for `direction` and `epoch`.
    pub fn mac(&self, direction: Direction, epoch: u64, bytes: &[u8]) -> [u8; MAC_LEN] {
        let h = match direction {
            Direction::ToController => self.after_key[0],
            Direction::ToHost => self.after_key[1],
        };
        blake2s_after_key(h, &[&epoch.to_le_bytes(), bytes])
    }
}

/// Keyed BLAKE2s (RFC 7693) with 16 bytes of output from the state `h` after the key block,
/// of the concatenation of `parts` (at least one byte: the epoch).
// `filled` stays within 0..=64, `n` within the room left: no slice is out of range.
#[allow(clippy::indexing_slicing, clippy::cast_possible_truncation)]
fn blake2s_after_key(mut h: [u32; 8], parts: &[&[u8]]) -> [u8; MAC_LEN] {
    let mut block = [0u8; 64];
    let mut filled = 0;
    let mut t: u64 = 64;
    for part in parts {
        let mut bytes = *part;
        while !bytes.is_empty() {
            if filled == 64 {
                t += 64;
                compress(&mut h, &block, t, false);
                filled = 0;
            }
            let n = bytes.len().min(64 - filled);
            let (head, tail) = bytes.split_at(n);
            block[filled..filled + n].copy_from_slice(head);
            filled += n;
            bytes = tail;
        }
    }
    block[filled..].fill(0);
    t += filled as u64;
    compress(&mut h, &block, t, true);
    let mut out = [0u8; MAC_LEN];
    for (o, w) in out.chunks_exact_mut(4).zip(h) {
        o.copy_from_slice(&w.to_le_bytes());
    }
    out
}

/// The MAC of `bytes` (an envelope up to its MAC) under `key` for `direction` and `epoch`
/// (a host's way; the controller keeps a [`MacKey`]).
pub fn mac(key: &AuthKey, direction: Direction, epoch: u64, bytes: &[u8]) -> [u8; MAC_LEN] {
    MacKey::new(key).mac(direction, epoch, bytes)
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
        match bytes.split_last() {
            Some((&crc, body)) if crc8(body) == crc => {}
            Some(_) => return Err(EnvelopeError::BadCrc),
            None => return Err(EnvelopeError::Malformed),
        }
        let envelope = Envelope::split(bytes)?;
        match envelope.inner.split_last() {
            Some((&c, b)) if crc8(b) == c => Ok(envelope),
            _ => Err(EnvelopeError::BadInnerCrc),
        }
    }

    /// Splits an envelope whose outer CRC the caller has checked, leaving the inner
    /// frame's CRC to its decoding: the controller's way, which reads the 1,400 bytes of
    /// a PENDING no more often than needed (each CRC pass costs about 5 instructions a
    /// byte on the Cortex-M7). Never panics.
    pub fn split(bytes: &'a [u8]) -> Result<Envelope<'a>, EnvelopeError> {
        if bytes.len() < ENVELOPE_OVERHEAD + FRAME_OVERHEAD
            || bytes.get(1) != Some(&(Tag::Auth as u8))
        {
            return Err(EnvelopeError::Malformed);
        }
        let Some((_, body)) = bytes.split_last() else {
            return Err(EnvelopeError::Malformed);
        };
        let (signed, mac) = body.split_at(body.len() - MAC_LEN);
        let inner = signed.get(ENVELOPE_HEADER..).unwrap_or_default();
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
        self.verify_with(&MacKey::new(key), direction, epoch)
    }

    /// [`Envelope::verify`] with a key made ready.
    pub fn verify_with(&self, key: &MacKey, direction: Direction, epoch: u64) -> bool {
        same_mac(&key.mac(direction, epoch, self.signed), self.mac)
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
    seal_with(
        &MacKey::new(key),
        direction,
        epoch,
        session,
        counter,
        inner,
        buf,
    )
}

/// [`seal`] with a key made ready.
pub fn seal_with(
    key: &MacKey,
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
    let m = key.mac(
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
    const PYTHON_ABC: &str = "a60ca9b5992f528144f29df8cf0140f2";

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
        assert_eq!(Envelope::open(&buf[..5]), Err(EnvelopeError::BadCrc));
        assert_eq!(Envelope::split(&buf[..5]), Err(EnvelopeError::Malformed));
        assert_eq!(Envelope::open(&[]), Err(EnvelopeError::Malformed));
    }

    /// The hand-written BLAKE2s agrees with RustCrypto's `blake2` crate, for every
    /// message length around the block boundaries, both personas.
    #[test]
    fn the_mac_is_rustcryptos_keyed_blake2s() {
        use blake2::Blake2sMac;
        use blake2::digest::consts::U16;
        use blake2::digest::{FixedOutput, Update};
        let key = AuthKey(core::array::from_fn(|i| (i * 7 + 3) as u8));
        let data: [u8; 300] = core::array::from_fn(|i| (i * 31 + 1) as u8);
        for len in (0..=200).chain([255, 256, 257, 300 - 8]) {
            for dir in [Direction::ToController, Direction::ToHost] {
                let mut m =
                    Blake2sMac::<U16>::new_with_salt_and_personal(Some(&key.0), &[], dir.persona())
                        .unwrap();
                m.update(&42u64.to_le_bytes());
                m.update(&data[..len]);
                let expected: [u8; MAC_LEN] = m.finalize_fixed().into();
                assert_eq!(mac(&key, dir, 42, &data[..len]), expected, "len {len}");
            }
        }
    }

    /// RFC 7693 Appendix B's BLAKE2s-256("abc") would need another output length; this is
    /// Python's `hashlib.blake2s(bytes(8) + b"abc", key=bytes(range(32)),
    /// digest_size=16, person=b"armH2C01")`.
    #[test]
    fn the_mac_matches_pythons_hashlib() {
        let key = AuthKey(core::array::from_fn(|i| i as u8));
        let m = mac(&key, Direction::ToController, 0, b"abc");
        let mut hex = [0u8; 2 * MAC_LEN];
        for (pair, b) in hex.chunks_exact_mut(2).zip(m) {
            pair[0] = b"0123456789abcdef"[usize::from(b >> 4)];
            pair[1] = b"0123456789abcdef"[usize::from(b & 15)];
        }
        assert_eq!(core::str::from_utf8(&hex).unwrap(), PYTHON_ABC);
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
