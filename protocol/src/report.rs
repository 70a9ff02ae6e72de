//! [`Report`]: what the controller sends back (ACK, LOCATION, USART_RECV, STATUS),
//! decoded from and encoded into a datagram.

use crate::codec::{u8_at, u16_le};
use crate::codes::{State, StatusCode, Tag};
use crate::diag::Diag;
use crate::error::{DecodeError, DecodeErrorKind, EncodeError, ExpectedLen, Field};
use crate::frame::{Frame, open, seal};
use crate::joint_desc::JointDescSet;
use crate::joint_limits::LimitsReport;
use crate::motion::MotionReport;
use crate::rx_counters::RxCounters;
use crate::stop_cause::StopReport;
use crate::types::{Ack, Location, StatusReport};
use crate::{FRAME_OVERHEAD, MAX_SERIAL_CHUNK, size};

/// A report from the controller to a host (docs/PROTOCOL.md, "Reports (controller to host)").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub enum Report<'a> {
    /// Reply to a command.
    Ack(Ack),
    /// Joint positions and state.
    Location(Location),
    /// 0..255 bytes read from the serial port.
    UsartRecv(&'a [u8]),
    /// Controller status.
    Status(StatusReport),
    /// Every joint's limits and the last refusal (the answer to LIMITS_GET).
    Limits(LimitsReport),
    /// What ended the last run (asked for with STATUS's request byte, bit 2; issue 31).
    StopCause(StopReport),
    /// The receive path's counters (STATUS's request byte bit 3; issue 30).
    RxCounters(RxCounters),
    /// The board's own timing counters (STATUS's request byte bit 6, issue 34).
    Diag(Diag),
    /// Override, hold and ramp (STATUS's request byte bit 4; issue 32).
    Motion(MotionReport),
    /// One joint's description, the answer to JOINT_DESC_GET (issue 31); the same data
    /// as JOINT_DESC_SET.
    JointDesc(JointDescSet),
}

impl<'a> Report<'a> {
    /// The tag this report travels under.
    pub fn tag(&self) -> Tag {
        match self {
            Report::Ack(_) => Tag::Ack,
            Report::Location(_) => Tag::Location,
            Report::UsartRecv(_) => Tag::UsartRecv,
            Report::Status(_) => Tag::Status,
            Report::Limits(_) => Tag::Limits,
            Report::StopCause(_) => Tag::StopCause,
            Report::RxCounters(_) => Tag::RxCounters,
            Report::Diag(_) => Tag::Diag,
            Report::Motion(_) => Tag::Motion,
            Report::JointDesc(_) => Tag::JointDesc,
        }
    }

    /// Bytes of data.
    pub fn data_len(&self) -> usize {
        match self {
            Report::Ack(_) => size::ACK,
            Report::Location(_) => size::LOCATION,
            Report::UsartRecv(_) => size::USART_RECV,
            Report::Status(_) => size::STATUS,
            Report::Limits(limits) => limits.data_len(),
            Report::StopCause(_) => size::STOP_CAUSE,
            Report::RxCounters(_) => size::RX_COUNTERS,
            Report::Diag(_) => size::DIAG,
            Report::Motion(_) => size::MOTION,
            Report::JointDesc(_) => size::JOINT_DESC_SET,
        }
    }

    /// Bytes of the whole encoded frame.
    pub fn encoded_len(&self) -> usize {
        self.data_len() + FRAME_OVERHEAD
    }

    /// Writes the frame with `seq` into `buf`; returns its length.
    pub fn encode(&self, seq: u8, buf: &mut [u8]) -> Result<usize, EncodeError> {
        if let Report::UsartRecv(bytes) = self
            && bytes.len() > MAX_SERIAL_CHUNK
        {
            return Err(EncodeError::InvalidContent);
        }
        seal(seq, self.tag(), self.data_len(), buf, |w| match self {
            Report::Ack(ack) => ack.write(w, 0),
            Report::Location(loc) => loc.write(w, 0),
            Report::UsartRecv(bytes) => {
                // At most MAX_SERIAL_CHUNK (255): checked above.
                w.u8(0, u8::try_from(bytes.len()).unwrap_or(u8::MAX));
                w.put(1, bytes);
            }
            Report::Status(status) => status.write(w, 0),
            Report::Limits(limits) => limits.write(w, 0),
            Report::StopCause(stop) => stop.write(w, 0),
            Report::RxCounters(counters) => counters.write(w, 0),
            Report::Diag(diag) => diag.write(w, 0),
            Report::Motion(motion) => motion.write(w, 0),
            Report::JointDesc(set) => set.write(w, 0),
        })
    }

    /// Decodes a datagram sent by the controller. Never panics.
    pub fn decode(bytes: &'a [u8]) -> Result<Frame<Report<'a>>, DecodeError> {
        let (seq, tag_byte, data) = open(bytes)?;
        let err = |kind| DecodeError {
            seq,
            tag: tag_byte,
            kind,
        };
        let exactly = |n: usize| {
            if data.len() == n {
                Ok(())
            } else {
                Err(err(DecodeErrorKind::BadLength {
                    expected: ExpectedLen::Exactly(n),
                    found: data.len(),
                }))
            }
        };
        let body = match Tag::from_u8(tag_byte) {
            None => return Err(err(DecodeErrorKind::UnknownTag)),
            Some(Tag::Ack) => {
                exactly(size::ACK)?;
                Report::Ack(Ack {
                    acked_tag: u8_at(data, 0),
                    status: StatusCode::from_u8(u8_at(data, 1))
                        .ok_or(err(DecodeErrorKind::OutOfRange(Field::Status)))?,
                    state: State::from_u8(u8_at(data, 2))
                        .ok_or(err(DecodeErrorKind::OutOfRange(Field::State)))?,
                    next_seq: u8_at(data, 3),
                    buffered: u16_le(data, 4),
                    free: u16_le(data, 6),
                })
            }
            Some(Tag::Location) => {
                if data.len() != size::LOCATION && data.len() != size::LOCATION_PACKED {
                    return Err(err(DecodeErrorKind::BadLength {
                        expected: ExpectedLen::Either(size::LOCATION, size::LOCATION_PACKED),
                        found: data.len(),
                    }));
                }
                let location = Location::read(data);
                // A host acts on the state, so a code outside the table is an error here
                // (LOCATION_SETTING ignores the byte instead).
                if State::from_u8(location.state).is_none() {
                    return Err(err(DecodeErrorKind::OutOfRange(Field::State)));
                }
                Report::Location(location)
            }
            Some(Tag::UsartRecv) => {
                exactly(size::USART_RECV)?;
                // `len` is at most 255 and the area 256 bytes, so `get` always succeeds.
                let len = usize::from(u8_at(data, 0));
                Report::UsartRecv(data.get(1..1 + len).unwrap_or_default())
            }
            Some(Tag::Status) => {
                exactly(size::STATUS)?;
                Report::Status(
                    StatusReport::read(data)
                        .ok_or(err(DecodeErrorKind::OutOfRange(Field::State)))?,
                )
            }
            Some(Tag::Limits) => {
                if data.len() != size::LIMITS && data.len() != size::LIMITS_WITH_ACCEL {
                    return Err(err(DecodeErrorKind::BadLength {
                        expected: ExpectedLen::Either(size::LIMITS, size::LIMITS_WITH_ACCEL),
                        found: data.len(),
                    }));
                }
                Report::Limits(LimitsReport::read(data))
            }
            Some(Tag::StopCause) => {
                exactly(size::STOP_CAUSE)?;
                Report::StopCause(StopReport::read(data))
            }
            Some(Tag::RxCounters) => {
                exactly(size::RX_COUNTERS)?;
                Report::RxCounters(RxCounters::read(data))
            }
            Some(Tag::Diag) => {
                exactly(size::DIAG)?;
                Report::Diag(Diag::read(data))
            }
            Some(Tag::Motion) => {
                exactly(size::MOTION)?;
                Report::Motion(MotionReport::read(data))
            }
            Some(Tag::JointDesc) => {
                exactly(size::JOINT_DESC_SET)?;
                Report::JointDesc(
                    JointDescSet::read(data)
                        .ok_or(err(DecodeErrorKind::OutOfRange(Field::JointDesc)))?,
                )
            }
            Some(_) => return Err(err(DecodeErrorKind::WrongDirection)),
        };
        Ok(Frame { seq, body })
    }
}
