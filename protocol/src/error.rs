//! What can be wrong with a frame, precisely enough for a status code on the wire and a
//! message a person can act on.

use core::fmt;

use crate::StatusCode;

/// Why a datagram is not a valid frame. `seq` and `tag` are the frame's own bytes (0 when
/// the datagram is too short to have them) so that the controller can ACK the error.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DecodeError {
    /// The frame's seq byte.
    pub seq: u8,
    /// The frame's tag byte.
    pub tag: u8,
    /// What is wrong.
    pub kind: DecodeErrorKind,
}

/// The ways a datagram can fail to decode.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecodeErrorKind {
    /// Fewer than 3 bytes: no seq, tag and CRC. Gets no reply.
    TooShort {
        /// Bytes received.
        len: usize,
    },
    /// The CRC byte does not match the frame.
    BadCrc {
        /// CRC-8/SMBUS computed over seq, tag and data.
        computed: u8,
        /// The frame's last byte.
        received: u8,
    },
    /// No command (or report) has this tag.
    UnknownTag,
    /// The data length does not fit the tag.
    BadLength {
        /// Lengths the tag allows.
        expected: ExpectedLen,
        /// Data bytes received.
        found: usize,
    },
    /// A field holds a value outside its range.
    OutOfRange(Field),
    /// A tag that only travels the other way (USART_RECV or ACK from a host).
    WrongDirection,
}

/// Data lengths a tag allows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ExpectedLen {
    /// Exactly this many bytes.
    Exactly(usize),
    /// Either of two forms (canonical first).
    Either(usize, usize),
    /// Any length in `min..=max`.
    Between(usize, usize),
    /// `1..=max` whole records of `unit` bytes.
    Records {
        /// Bytes per record.
        unit: usize,
        /// Most records.
        max: usize,
    },
}

/// A field whose value can be out of range.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Field {
    /// NEW's point count (1..65535).
    PointCount,
    /// JOINTS_COUNT (1..8).
    Joints,
    /// UPLOAD_PERIOD (1000..1000000 us).
    UploadPeriod,
    /// Pwm.PSC (16 bits).
    Psc,
    /// Pwm.ARR (16 bits).
    Arr,
    /// Pwm.CCR1 (<= ARR).
    Ccr1,
    /// UartInit.BaudRate (300..4000000).
    BaudRate,
    /// TOGGLE_ENABLE_PINS mask (bits 0-8).
    EnableMask,
    /// A point's duration (>= 1 us); the index of the point in its frame.
    Duration(u8),
    /// A state code (reports).
    State,
    /// A status code (ACK).
    Status,
    /// NET_SET's settings (mode 0 or 1; a usable unicast address, prefix and gateway).
    NetSettings,
    /// DISCOVER_REPLY's owner state (0..2).
    Owner,
    /// SET_ENABLE's action (0 disable, 1 enable).
    EnableAction,
    /// STATUS's request byte (bits 0-4 only).
    StatusAsk,
    /// LIMITS_SET's joint (0-7) or range (min above max); ACCEL_SET's joint.
    JointLimits,
    /// LIMITS_GET's request byte (bit 0 only).
    LimitsAsk,
    /// JOINT_DESC_SET's or JOINT_DESC_GET's joint (0-7), unit, name or scale.
    JointDesc,
    /// OVERRIDE's percent (1..200).
    Override,
    /// ESTOP_CATEGORY's byte (0 or 1).
    EstopCategory,
    /// HOMING_SET's or HOMING_GET's joint (0-7), flags (bits 0-2), or settings that cannot
    /// run (a zero rate, back-off or travel on an enabled joint); the HOMING or SWITCHES
    /// report's codes.
    Homing,
}

impl DecodeError {
    /// The ACK status the controller answers with; `None` for a frame too short to answer.
    pub fn status(&self) -> Option<StatusCode> {
        Some(match self.kind {
            DecodeErrorKind::TooShort { .. } => return None,
            DecodeErrorKind::BadCrc { .. } => StatusCode::BadCrc,
            DecodeErrorKind::UnknownTag => StatusCode::UnknownTag,
            DecodeErrorKind::BadLength { .. } => StatusCode::BadLength,
            DecodeErrorKind::OutOfRange(Field::Duration(_)) => StatusCode::InvalidPoint,
            DecodeErrorKind::OutOfRange(_) => StatusCode::InvalidConfig,
            DecodeErrorKind::WrongDirection => StatusCode::Unsupported,
        })
    }
}

impl fmt::Display for ExpectedLen {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            ExpectedLen::Exactly(n) => write!(f, "{n} bytes"),
            ExpectedLen::Either(a, b) => write!(f, "{a} or {b} bytes"),
            ExpectedLen::Between(a, b) => write!(f, "{a} to {b} bytes"),
            ExpectedLen::Records { unit, max } => {
                write!(f, "1 to {max} records of {unit} bytes")
            }
        }
    }
}

impl fmt::Display for Field {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Field::PointCount => f.write_str("NEW point count must be 1..65535"),
            Field::Joints => f.write_str("joint count must be 1..8"),
            Field::UploadPeriod => f.write_str("upload period must be 1000..1000000 us"),
            Field::Psc => f.write_str("PWM PSC must fit 16 bits"),
            Field::Arr => f.write_str("PWM ARR must fit 16 bits"),
            Field::Ccr1 => f.write_str("PWM CCR1 must not exceed ARR"),
            Field::BaudRate => f.write_str("baud rate must be 300..4000000"),
            Field::EnableMask => f.write_str("enable mask may only use bits 0-8"),
            Field::Duration(i) => write!(f, "point {i} has a duration under 1 us"),
            Field::State => f.write_str("unknown state code"),
            Field::Status => f.write_str("unknown status code"),
            Field::NetSettings => f.write_str(
                "network settings must be DHCP, or a unicast address with a prefix of 1..32 and a gateway inside its subnet",
            ),
            Field::Owner => f.write_str("unknown owner state"),
            Field::StatusAsk => f.write_str("STATUS request byte may only use bits 0-6"),
            Field::Override => f.write_str("OVERRIDE percent must be 1..200"),
            Field::EstopCategory => f.write_str("ESTOP_CATEGORY must be 0 or 1"),
            Field::JointLimits => {
                f.write_str("LIMITS_SET needs a joint of 0-7 and min not above max")
            }
            Field::LimitsAsk => f.write_str("LIMITS_GET request byte may only use bit 0"),
            Field::JointDesc => f.write_str(
                "JOINT_DESC needs a joint of 0-7, a unit of 0-3, a UTF-8 name of at most \
                 16 bytes padded with zeros and a finite scale",
            ),
            Field::EnableAction => {
                f.write_str("SET_ENABLE action must be 0 (disable) or 1 (enable)")
            }
            Field::Homing => f.write_str(
                "HOMING_SET needs a joint of 0-7, flags in bits 0-2 and, when enabled, \
                 non-zero rates, back-off and travel",
            ),
        }
    }
}

impl fmt::Display for DecodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let name = crate::Tag::name_of(self.tag);
        match self.kind {
            DecodeErrorKind::TooShort { len } => {
                write!(
                    f,
                    "datagram of {len} bytes is too short for a frame (3 at least)"
                )
            }
            DecodeErrorKind::BadCrc { computed, received } => write!(
                f,
                "CRC mismatch in seq {} tag {:#04x}: frame says {received:#04x}, content gives {computed:#04x}",
                self.seq, self.tag
            ),
            DecodeErrorKind::UnknownTag => write!(f, "unknown tag {:#04x}", self.tag),
            DecodeErrorKind::BadLength { expected, found } => write!(
                f,
                "{name} ({:#04x}) needs {expected} of data, got {found}",
                self.tag
            ),
            DecodeErrorKind::OutOfRange(field) => write!(f, "{name}: {field}"),
            DecodeErrorKind::WrongDirection => {
                write!(f, "{name} ({:#04x}) only goes the other way", self.tag)
            }
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for DecodeError {}

/// Why a frame could not be encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum EncodeError {
    /// The caller's buffer is shorter than the frame.
    BufferTooSmall {
        /// Bytes the frame needs.
        needed: usize,
        /// Bytes the buffer has.
        available: usize,
    },
    /// The content cannot form a valid frame (0 or more than 12 points, 0 or more than
    /// 255 serial bytes).
    InvalidContent,
}

impl fmt::Display for EncodeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            EncodeError::BufferTooSmall { needed, available } => {
                write!(f, "frame needs {needed} bytes, buffer has {available}")
            }
            EncodeError::InvalidContent => {
                f.write_str("content cannot form a frame (1..12 points, 1..255 serial bytes)")
            }
        }
    }
}

#[cfg(feature = "std")]
impl std::error::Error for EncodeError {}
