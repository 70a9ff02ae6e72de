//! The arm controller's wire protocol, as fixed by `docs/PROTOCOL.md`.
//!
//! One frame per UDP datagram: `| seq u8 | tag u8 | data | crc u8 |`, CRC-8/SMBUS over
//! everything before the CRC, little-endian fields laid out as a 32-bit ARM C compiler lays
//! out the manual's structs (NEW's count and TOGGLE_ENABLE_PINS's mask are big-endian).
//!
//! [`Command`] is what a host sends, [`Report`] what the controller sends back. Both decode
//! from a byte slice without allocating or panicking, and encode into the caller's buffer.
//! The crate is `no_std` and shared by the firmware, the simulator and the host tools.
#![no_std]
#![warn(missing_docs)]
// Tests index and unwrap freely: a failing test is meant to panic.
#![cfg_attr(not(test), warn(clippy::indexing_slicing, clippy::unwrap_used))]
#![cfg_attr(not(test), warn(clippy::cast_possible_truncation))]

#[cfg(feature = "std")]
extern crate std;

pub mod auth;
mod codec;
mod codes;
mod command;
mod diag;
mod error;
mod frame;
mod homing;
mod joint_desc;
mod joint_limits;
pub mod limits;
mod motion;
mod net;
mod report;
mod rx_counters;
mod stop_cause;
mod types;

pub use codes::{State, StatusCode, Tag};
pub use command::{Command, StatusAsk};
pub use diag::Diag;
pub use error::{DecodeError, DecodeErrorKind, EncodeError, ExpectedLen, Field};
pub use frame::{Frame, PointList, PointsIter, crc8};
pub use homing::{HomingFailure, HomingPhase, HomingSet, HomingSettings, SwitchesReport};
pub use joint_desc::{JointDesc, JointDescSet, JointUnit, NAME_LEN as JOINT_NAME_LEN};
pub use joint_limits::{JointLimits, LimitsReport, LimitsSet, Refusal, RefusalReason};
pub use limits::DEFAULT_WINDOW;
pub use motion::{
    ControlledStop, EStopCategory, MotionFlags, MotionReport, OVERRIDE_MAX_PERCENT,
    OVERRIDE_MIN_PERCENT, OverrideLimit,
};
pub use net::{DiscoverReply, NetSettings, OwnerState};
pub use report::Report;
pub use rx_counters::RxCounters;
pub use stop_cause::{StopCause, StopReport};
pub use types::{
    Ack, Location, MoreFlags, Point, Pwm, StatusFlags, StatusReport, UartInit, UartMode,
};

/// UDP port the controller listens on.
pub const PORT: u16 = 8510;
/// Largest datagram payload: Ethernet MTU 1500 less the IPv4 and UDP headers.
pub const MAX_DATAGRAM: usize = 1472;
/// seq, tag and crc around the data.
pub const FRAME_OVERHEAD: usize = 3;
/// Largest data part of a frame.
pub const MAX_DATA: usize = MAX_DATAGRAM - FRAME_OVERHEAD;
/// Joints a Point or Location carries, whatever the arm uses.
pub const MAX_JOINTS: usize = 8;
/// Points in one PENDING frame: 12 * 116 = 1392 bytes fit one datagram, 13 do not.
pub const MAX_POINTS_PER_FRAME: usize = 12;
/// Bytes of one USART_SEND or USART_RECV payload at most.
pub const MAX_SERIAL_CHUNK: usize = 255;
/// Protocol version reported in STATUS.
pub const VERSION: [u8; 3] = [1, 0, 0];

/// Encoded sizes of the wire structs.
pub mod size {
    /// `Point`: duration + four hint arrays + position.
    pub const POINT: usize = 116;
    /// `Location`: 33 bytes of fields + 3 padding bytes.
    pub const LOCATION: usize = 36;
    /// `Location` without its padding (tolerated on receipt).
    pub const LOCATION_PACKED: usize = 33;
    /// `Pwm`.
    pub const PWM: usize = 16;
    /// `UartInit`.
    pub const UART_INIT: usize = 28;
    /// `UartInit` as printed in the manual, with `Parity` twice (tolerated on receipt).
    pub const UART_INIT_MANUAL: usize = 32;
    /// ACK data.
    pub const ACK: usize = 8;
    /// STATUS report data.
    pub const STATUS: usize = 36;
    /// USART_RECV data: `len` + a 256-byte area.
    pub const USART_RECV: usize = 257;
    /// NET_SET data: mode, ip, prefix length, gateway.
    pub const NET_SET: usize = 10;
    /// DISCOVER_REPLY data.
    pub const DISCOVER_REPLY: usize = 27;
    /// SET_ENABLE data: mask (u16 little-endian), action (u8).
    pub const SET_ENABLE: usize = 3;
    /// LIMITS_SET data: joint, 3 reserved, min, max, max_rate_hz.
    pub const LIMITS_SET: usize = 16;
    /// LIMITS report data: 8 joints' limits (12 bytes each), the last refusal (16).
    pub const LIMITS: usize = 12 * crate::MAX_JOINTS + 16;
    /// LIMITS report data when LIMITS_GET asks for the accelerations too (issue 31): the
    /// 112 bytes, then each joint's `max_accel_steps_s2` (u32).
    pub const LIMITS_WITH_ACCEL: usize = LIMITS + 4 * crate::MAX_JOINTS;
    /// ACCEL_SET data: joint, 3 reserved, max_accel_steps_s2 (u32).
    pub const ACCEL_SET: usize = 8;
    /// One joint's description (issue 31): name 16, unit, 3 reserved, zero offset i32,
    /// scale f64.
    pub const JOINT_DESC: usize = 32;
    /// JOINT_DESC_SET data and the JOINT_DESC report's: joint, 3 reserved, description.
    pub const JOINT_DESC_SET: usize = 4 + JOINT_DESC;
    /// JOINT_DESC_GET data: the joint.
    pub const JOINT_DESC_GET: usize = 1;
    /// STOP_CAUSE report data: cause, detail, 2 reserved, the STOPPED's sender address
    /// and port, 2 reserved.
    pub const STOP_CAUSE: usize = 12;
    /// RX_COUNTERS data: six u32 counters.
    pub const RX_COUNTERS: usize = 24;
    /// DIAG data: nine 32-bit counters and clocks (issue 34).
    pub const DIAG: usize = 36;
    /// OVERRIDE data: the percent (1..200).
    pub const OVERRIDE: usize = 1;
    /// ESTOP_CATEGORY data: the category (0 or 1).
    pub const ESTOP_CATEGORY: usize = 1;
    /// MOTION report data: factor, flags, rate (u16), last controlled stop, refused joint
    /// and limit, 1 reserved.
    pub const MOTION: usize = 8;
    /// HOMING_SET data and the HOMING report's: joint, flags, order, 1 reserved, four u32
    /// (seek and approach rates, back-off, max travel), offset i32 (issue 33).
    pub const HOMING_SET: usize = 24;
    /// HOMING_GET data: the joint.
    pub const HOMING_GET: usize = 1;
    /// SWITCHES report data: phase, joint, error, homed, home/min/max pressed, latched.
    pub const SWITCHES: usize = 8;
    /// HELLO data: the host's nonce.
    pub const HELLO: usize = crate::auth::NONCE_LEN;
}
