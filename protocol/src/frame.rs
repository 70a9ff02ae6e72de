//! Frames: decoding a datagram into a typed command or report, and encoding one back.

use crate::codec::{Writer, u8_at};
use crate::codes::Tag;
use crate::error::{DecodeError, DecodeErrorKind, EncodeError};
use crate::types::Point;
use crate::{FRAME_OVERHEAD, size};

const CRC8: crc::Crc<u8> = crc::Crc::<u8>::new(&crc::CRC_8_SMBUS);

/// CRC-8/SMBUS (poly 0x07, init 0, no reflection, no xorout) of `bytes`.
pub fn crc8(bytes: &[u8]) -> u8 {
    CRC8.checksum(bytes)
}

/// A decoded frame: the host's seq and the typed content.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub struct Frame<T> {
    /// Sequence number.
    pub seq: u8,
    /// Content.
    pub body: T,
}

/// The points of a PENDING frame: either still in wire form (decoded, zero-copy) or a
/// slice of [`Point`]s (to encode).
#[derive(Clone, Copy, Debug)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PointList<'a> {
    /// Whole 116-byte records, as received.
    Wire(&'a [u8]),
    /// Points to send.
    Points(&'a [Point]),
}

impl<'a> PointList<'a> {
    /// Number of points.
    pub fn len(&self) -> usize {
        match self {
            PointList::Wire(b) => b.len() / size::POINT,
            PointList::Points(p) => p.len(),
        }
    }
    /// Whether there are no points.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Point `i`, if there is one.
    pub fn get(&self, i: usize) -> Option<Point> {
        match self {
            PointList::Wire(b) => {
                // Checked so that no index, however large, can overflow.
                let start = i.checked_mul(size::POINT)?;
                b.get(start..start.checked_add(size::POINT)?)
                    .map(Point::read)
            }
            PointList::Points(p) => p.get(i).copied(),
        }
    }
    /// The points in order.
    pub fn iter(&self) -> PointsIter<'a> {
        PointsIter {
            list: *self,
            next: 0,
        }
    }
}

impl PartialEq for PointList<'_> {
    fn eq(&self, other: &Self) -> bool {
        self.len() == other.len() && self.iter().eq(other.iter())
    }
}
impl Eq for PointList<'_> {}

#[cfg(feature = "serde")]
impl serde::Serialize for PointList<'_> {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_seq(self.iter())
    }
}

/// Iterator over a [`PointList`].
#[derive(Clone, Debug)]
pub struct PointsIter<'a> {
    list: PointList<'a>,
    next: usize,
}

impl Iterator for PointsIter<'_> {
    type Item = Point;
    fn next(&mut self) -> Option<Point> {
        let p = self.list.get(self.next)?;
        self.next += 1;
        Some(p)
    }
    fn size_hint(&self) -> (usize, Option<usize>) {
        let n = self.list.len().saturating_sub(self.next);
        (n, Some(n))
    }
}

impl ExactSizeIterator for PointsIter<'_> {}

/// Checks length and CRC, returns seq, tag byte and data.
pub(crate) fn open(bytes: &[u8]) -> Result<(u8, u8, &[u8]), DecodeError> {
    let too_short = DecodeError {
        seq: u8_at(bytes, 0),
        tag: u8_at(bytes, 1),
        kind: DecodeErrorKind::TooShort { len: bytes.len() },
    };
    let Some((&crc, body)) = bytes.split_last() else {
        return Err(too_short);
    };
    let [seq, tag, data @ ..] = body else {
        return Err(too_short);
    };
    let (seq, tag) = (*seq, *tag);
    let computed = crc8(body);
    if computed != crc {
        return Err(DecodeError {
            seq,
            tag,
            kind: DecodeErrorKind::BadCrc {
                computed,
                received: crc,
            },
        });
    }
    Ok((seq, tag, data))
}

/// Builds a frame around `data_len` bytes written by `fill`.
pub(crate) fn seal(
    seq: u8,
    tag: Tag,
    data_len: usize,
    buf: &mut [u8],
    fill: impl FnOnce(&mut Writer<'_>),
) -> Result<usize, EncodeError> {
    let needed = data_len + FRAME_OVERHEAD;
    let too_small = EncodeError::BufferTooSmall {
        needed,
        available: buf.len(),
    };
    let Some((crc, body)) = buf.get_mut(..needed).and_then(|f| f.split_last_mut()) else {
        return Err(too_small);
    };
    let Some((header, data)) = body.split_first_chunk_mut::<2>() else {
        return Err(too_small);
    };
    *header = [seq, tag.into()];
    data.fill(0);
    fill(&mut Writer { buf: data });
    *crc = crc8(body);
    Ok(needed)
}
