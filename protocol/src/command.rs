//! [`Command`]: what a host sends, decoded from and encoded into a datagram.

use crate::auth::AuthKey;
use crate::codec::{u8_at, u16_be, u16_le, u32_le};
use crate::codes::Tag;
use crate::error::{DecodeError, DecodeErrorKind, EncodeError, ExpectedLen, Field};
use crate::frame::{Frame, PointList, open, seal};
use crate::homing::HomingSet;
use crate::joint_desc::JointDescSet;
use crate::joint_limits::{JointLimits, LimitsSet};
use crate::motion::EStopCategory;
use crate::net::NetSettings;
use crate::types::{Location, Pwm, UartInit};
use crate::{FRAME_OVERHEAD, MAX_POINTS_PER_FRAME, MAX_SERIAL_CHUNK, limits, size};

/// A command from a host to the controller (docs/PROTOCOL.md, "Commands (host to controller)").
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize))]
pub enum Command<'a> {
    /// Start an upload of `count` points (big-endian on the wire).
    New {
        /// Points the trajectory will have, 1..65535.
        count: u16,
    },
    /// 1..12 points to append.
    Pending(PointList<'a>),
    /// Start executing.
    Runing,
    /// Stop at once and drop the buffer.
    Stopped,
    /// Location reports on.
    UploadStart,
    /// Location reports off.
    UploadStop,
    /// Gripper PWM on.
    PwmStart(Pwm),
    /// Gripper PWM off.
    PwmStop,
    /// Open the serial pass-through.
    UsartStart(UartInit),
    /// Close it.
    UsartStop,
    /// 1..255 bytes to write to the serial port.
    UsartSend(&'a [u8]),
    /// GPIO_0 high.
    Pin0On,
    /// GPIO_0 low.
    Pin0Off,
    /// GPIO_1 high.
    Pin1On,
    /// GPIO_1 low.
    Pin1Off,
    /// Toggle the ENABLE of every driver (`None`) or of the masked ones.
    ToggleEnablePins {
        /// Bits 0-7 joints, bit 8 gripper (big-endian on the wire).
        mask: Option<u16>,
    },
    /// Move every joint to zero.
    Return,
    /// Set the joint count, 1..8.
    JointsCount(u8),
    /// Set the current joint positions.
    LocationSetting(Location),
    /// Ask for a STATUS report.
    Status,
    /// Set the location report period.
    UploadPeriod {
        /// Microseconds, 1000..1000000.
        period_us: u32,
    },
    /// Who is there? (answered with a DISCOVER_REPLY by any controller, to any host).
    Discover,
    /// Store new network settings, applied after the next reset.
    NetSet(NetSettings),
    /// Clear the wired e-stop input's latch (refused while the input is open).
    EstopReset,
    /// Open an authenticated session (docs/PROTOCOL.md section 13).
    Hello {
        /// Random bytes the HELLO_REPLY echoes.
        nonce: [u8; crate::auth::NONCE_LEN],
    },
    /// Set the controller's key, or clear it (`None`, no data).
    SetKey(Option<AuthKey>),
    /// Give the controller up (the owner only): any host may take it at once.
    Release,
    /// Clear the hard-limit latch (issue 33; no data).
    Unlock,
    /// Set one joint's limits (issue 23).
    LimitsSet(LimitsSet),
    /// Ask for the LIMITS report.
    LimitsGet,
    /// LIMITS_GET with its request byte 0x01 (issue 31): the LIMITS report with each
    /// joint's `max_accel_steps_s2` after the 112 bytes.
    LimitsGetWithAccel,
    /// Set one joint's most acceleration (issue 31), kept with its limits.
    AccelSet {
        /// The joint, 0-7.
        joint: u8,
        /// Most steps/s² between consecutive segments (docs/PROTOCOL.md, ACCEL_SET);
        /// 0: none.
        max_accel_steps_s2: u32,
    },
    /// Set one joint's description: name, units, scale (issue 31), kept with its limits.
    JointDescSet(JointDescSet),
    /// Ask for one joint's JOINT_DESC report (issue 31; read-only, any host).
    JointDescGet {
        /// The joint, 0-7.
        joint: u8,
    },
    /// Run the homing cycle on the home switches (issue 33; no data).
    Home,
    /// Set one joint's homing settings (issue 33), kept with its limits.
    HomingSet(HomingSet),
    /// Ask for one joint's HOMING report (issue 33; the owner, as LIMITS_GET).
    HomingGet {
        /// The joint, 0-7.
        joint: u8,
    },
    /// STATUS with its request byte (issue 23): what else to answer, and whether a host
    /// that does not own the controller wants only to look.
    StatusWith(StatusAsk),
    /// Decelerate along the path to a standstill and wait (issue 32).
    Hold,
    /// Accelerate back after a HOLD (issue 32).
    Resume,
    /// Set the speed override (issue 32).
    Override {
        /// Percent, 1..200.
        percent: u8,
    },
    /// Set the wired e-stop input's stop category (issue 32), kept in the settings.
    EstopCategory(EStopCategory),
    /// Enable (`enable`) or disable the masked drivers, leaving the others as they are
    /// (issue 23: an explicit form beside TOGGLE_ENABLE_PINS).
    SetEnable {
        /// Bits 0-7 joints, bit 8 gripper (little-endian on the wire, unlike TOGGLE's).
        mask: u16,
        /// `true`: holding; `false`: limp.
        enable: bool,
    },
}

/// LIMITS_GET's request byte (issue 31): the LIMITS report with the accelerations.
const LIMITS_WITH_ACCEL: u8 = 0x01;

/// STATUS's request byte (docs/PROTOCOL.md, STATUS): plain STATUS (no data) asks for
/// neither.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct StatusAsk {
    /// Bit 0: a LOCATION report (positions and state) to the asker too, right after the
    /// STATUS report.
    pub location: bool,
    /// Bit 1: only look: from a host that does not own the controller, answered read-only
    /// even when the controller is free (it never makes the asker the owner).
    pub look_only: bool,
    /// Bit 2: a STOP_CAUSE report (what ended the last run, who sent the STOPPED) to the
    /// asker too, after the STATUS report and the LOCATION (issue 31).
    pub stop_cause: bool,
    /// Bit 3: an RX_COUNTERS report (the receive path's drops) to the asker too, last:
    /// after the STATUS report, the LOCATION and the STOP_CAUSE (issue 30; bit 2 went to
    /// issue 31's STOP_CAUSE first).
    pub counters: bool,
    /// Bit 6: a DIAG report (the board's own timing counters) to the asker too, after
    /// every other report this byte asks for (issue 34; bits 4-5 are other issues').
    pub diag: bool,
    /// Bit 4: a MOTION report (override, hold, ramp; issue 32) to the asker too, after
    /// the RX_COUNTERS and before the DIAG.
    pub motion: bool,
    /// Bit 5: a SWITCHES report (the homing cycle's progress, the switch inputs) to the
    /// asker too, after the others (issue 33).
    pub switches: bool,
}

impl StatusAsk {
    /// Bit 0.
    pub const LOCATION: u8 = 1 << 0;
    /// Bit 1.
    pub const LOOK_ONLY: u8 = 1 << 1;
    /// Bit 2.
    pub const STOP_CAUSE: u8 = 1 << 2;
    /// Bit 3.
    pub const COUNTERS: u8 = 1 << 3;
    /// Bit 6.
    pub const DIAG: u8 = 1 << 6;
    /// Bit 4.
    pub const MOTION: u8 = 1 << 4;
    /// Bit 5 (bit 4 is issue 32's).
    pub const SWITCHES: u8 = 1 << 5;

    /// The byte on the wire.
    pub const fn byte(self) -> u8 {
        (if self.location { Self::LOCATION } else { 0 })
            | (if self.look_only { Self::LOOK_ONLY } else { 0 })
            | (if self.stop_cause { Self::STOP_CAUSE } else { 0 })
            | (if self.counters { Self::COUNTERS } else { 0 })
            | (if self.diag { Self::DIAG } else { 0 })
            | (if self.motion { Self::MOTION } else { 0 })
            | (if self.switches { Self::SWITCHES } else { 0 })
    }

    /// The request of a byte, `None` with other bits set.
    pub const fn from_byte(b: u8) -> Option<StatusAsk> {
        let known = Self::LOCATION
            | Self::LOOK_ONLY
            | Self::STOP_CAUSE
            | Self::COUNTERS
            | Self::MOTION
            | Self::SWITCHES
            | Self::DIAG;
        if b & !known != 0 {
            return None;
        }
        Some(StatusAsk {
            location: b & Self::LOCATION != 0,
            look_only: b & Self::LOOK_ONLY != 0,
            stop_cause: b & Self::STOP_CAUSE != 0,
            counters: b & Self::COUNTERS != 0,
            diag: b & Self::DIAG != 0,
            motion: b & Self::MOTION != 0,
            switches: b & Self::SWITCHES != 0,
        })
    }
}

impl<'a> Command<'a> {
    /// The tag this command travels under.
    pub fn tag(&self) -> Tag {
        match self {
            Command::New { .. } => Tag::New,
            Command::Pending(_) => Tag::Pending,
            Command::Runing => Tag::Runing,
            Command::Stopped => Tag::Stopped,
            Command::UploadStart => Tag::UploadStart,
            Command::UploadStop => Tag::UploadStop,
            Command::PwmStart(_) => Tag::PwmStart,
            Command::PwmStop => Tag::PwmStop,
            Command::UsartStart(_) => Tag::UsartStart,
            Command::UsartStop => Tag::UsartStop,
            Command::UsartSend(_) => Tag::UsartSend,
            Command::Pin0On => Tag::Pin0On,
            Command::Pin0Off => Tag::Pin0Off,
            Command::Pin1On => Tag::Pin1On,
            Command::Pin1Off => Tag::Pin1Off,
            Command::ToggleEnablePins { .. } => Tag::ToggleEnablePins,
            Command::Return => Tag::Return,
            Command::JointsCount(_) => Tag::JointsCount,
            Command::LocationSetting(_) => Tag::Location,
            Command::Status => Tag::Status,
            Command::UploadPeriod { .. } => Tag::UploadPeriod,
            Command::Discover => Tag::Discover,
            Command::NetSet(_) => Tag::NetSet,
            Command::EstopReset => Tag::EstopReset,
            Command::Hello { .. } => Tag::Hello,
            Command::SetKey(_) => Tag::SetKey,
            Command::SetEnable { .. } => Tag::SetEnable,
            Command::Release => Tag::Release,
            Command::Unlock => Tag::Unlock,
            Command::Hold => Tag::Hold,
            Command::Resume => Tag::Resume,
            Command::Override { .. } => Tag::Override,
            Command::EstopCategory(_) => Tag::EstopCategory,
            Command::LimitsSet(_) => Tag::LimitsSet,
            Command::LimitsGet | Command::LimitsGetWithAccel => Tag::LimitsGet,
            Command::AccelSet { .. } => Tag::AccelSet,
            Command::JointDescSet(_) => Tag::JointDescSet,
            Command::JointDescGet { .. } => Tag::JointDescGet,
            Command::StatusWith(_) => Tag::Status,
            Command::Home => Tag::Home,
            Command::HomingSet(_) => Tag::HomingSet,
            Command::HomingGet { .. } => Tag::HomingGet,
        }
    }

    /// Bytes of data in the canonical encoding.
    pub fn data_len(&self) -> usize {
        match self {
            Command::New { .. } => 2,
            Command::Pending(points) => points.len() * size::POINT,
            Command::PwmStart(_) => size::PWM,
            Command::UsartStart(_) => size::UART_INIT,
            Command::UsartSend(bytes) => bytes.len(),
            Command::ToggleEnablePins { mask: Some(_) } => 2,
            Command::JointsCount(_) => 1,
            Command::LocationSetting(_) => size::LOCATION,
            Command::UploadPeriod { .. } => 4,
            Command::NetSet(_) => size::NET_SET,
            Command::Hello { .. } => size::HELLO,
            Command::SetKey(Some(_)) => crate::auth::KEY_LEN,
            Command::SetEnable { .. } => size::SET_ENABLE,
            Command::StatusWith(_) => 1,
            Command::LimitsSet(_) => size::LIMITS_SET,
            Command::LimitsGetWithAccel => 1,
            Command::AccelSet { .. } => size::ACCEL_SET,
            Command::JointDescSet(_) => size::JOINT_DESC_SET,
            Command::JointDescGet { .. } => size::JOINT_DESC_GET,
            Command::Override { .. } => size::OVERRIDE,
            Command::EstopCategory(_) => size::ESTOP_CATEGORY,
            Command::HomingSet(_) => size::HOMING_SET,
            Command::HomingGet { .. } => size::HOMING_GET,
            _ => 0,
        }
    }

    /// Bytes of the whole encoded frame.
    pub fn encoded_len(&self) -> usize {
        self.data_len() + FRAME_OVERHEAD
    }

    /// Writes the frame with `seq` into `buf`; returns its length.
    pub fn encode(&self, seq: u8, buf: &mut [u8]) -> Result<usize, EncodeError> {
        match self {
            Command::Pending(p) if p.is_empty() || p.len() > MAX_POINTS_PER_FRAME => {
                return Err(EncodeError::InvalidContent);
            }
            // A partial record would be silently dropped: refuse it instead.
            Command::Pending(PointList::Wire(b)) if b.len() % size::POINT != 0 => {
                return Err(EncodeError::InvalidContent);
            }
            Command::UsartSend(b) if b.is_empty() || b.len() > MAX_SERIAL_CHUNK => {
                return Err(EncodeError::InvalidContent);
            }
            _ => {}
        }
        seal(seq, self.tag(), self.data_len(), buf, |w| match self {
            Command::New { count } => w.put(0, &count.to_be_bytes()),
            Command::Pending(PointList::Wire(bytes)) => w.put(0, bytes),
            Command::Pending(PointList::Points(points)) => {
                for (i, p) in points.iter().enumerate() {
                    p.write(w, i * size::POINT);
                }
            }
            Command::PwmStart(pwm) => {
                w.u32(0, pwm.psc);
                w.u32(4, pwm.arr);
                w.u32(8, pwm.ccr1);
                w.u32(12, pwm.pulse_count as u32);
            }
            Command::UsartStart(init) => init.write(w, 0),
            Command::UsartSend(bytes) => w.put(0, bytes),
            Command::ToggleEnablePins { mask: Some(mask) } => w.put(0, &mask.to_be_bytes()),
            Command::JointsCount(n) => w.u8(0, *n),
            Command::LocationSetting(loc) => loc.write(w, 0),
            Command::UploadPeriod { period_us } => w.u32(0, *period_us),
            Command::NetSet(net) => net.write(w, 0),
            Command::Hello { nonce } => w.put(0, nonce),
            Command::SetKey(Some(key)) => w.put(0, &key.0),
            Command::SetEnable { mask, enable } => {
                w.u16(0, *mask);
                w.u8(2, u8::from(*enable));
            }
            Command::StatusWith(ask) => w.u8(0, ask.byte()),
            Command::LimitsSet(set) => {
                w.put(0, &[set.joint, 0, 0, 0]);
                set.limits.write(w, 4);
            }
            Command::LimitsGetWithAccel => w.u8(0, LIMITS_WITH_ACCEL),
            Command::AccelSet {
                joint,
                max_accel_steps_s2,
            } => {
                w.put(0, &[*joint, 0, 0, 0]);
                w.u32(4, *max_accel_steps_s2);
            }
            Command::JointDescSet(set) => set.write(w, 0),
            Command::JointDescGet { joint } => w.u8(0, *joint),
            Command::Override { percent } => w.u8(0, *percent),
            Command::EstopCategory(category) => w.u8(0, *category as u8),
            Command::HomingSet(set) => set.write(w, 0),
            Command::HomingGet { joint } => w.u8(0, *joint),
            _ => {}
        })
    }

    /// Decodes a datagram sent to the controller. Never panics.
    pub fn decode(bytes: &'a [u8]) -> Result<Frame<Command<'a>>, DecodeError> {
        let (seq, tag_byte, data) = open(bytes)?;
        let err = |kind| DecodeError {
            seq,
            tag: tag_byte,
            kind,
        };
        let bad_len = |expected| {
            err(DecodeErrorKind::BadLength {
                expected,
                found: data.len(),
            })
        };
        let exactly = |n: usize| {
            if data.len() == n {
                Ok(())
            } else {
                Err(bad_len(ExpectedLen::Exactly(n)))
            }
        };
        let out_of_range = |field| err(DecodeErrorKind::OutOfRange(field));
        let Some(tag) = Tag::from_u8(tag_byte) else {
            return Err(err(DecodeErrorKind::UnknownTag));
        };
        let body = match tag {
            Tag::New => {
                exactly(2)?;
                let count = u16_be(data, 0);
                if count == 0 {
                    return Err(out_of_range(Field::PointCount));
                }
                Command::New { count }
            }
            Tag::Pending => {
                let records = data.len() / size::POINT;
                if data.len() % size::POINT != 0 || records == 0 || records > MAX_POINTS_PER_FRAME {
                    return Err(bad_len(ExpectedLen::Records {
                        unit: size::POINT,
                        max: MAX_POINTS_PER_FRAME,
                    }));
                }
                let points = PointList::Wire(data);
                if let Some(i) = points.iter().position(|p| p.duration < 1) {
                    // i < MAX_POINTS_PER_FRAME (12).
                    return Err(out_of_range(Field::Duration(
                        u8::try_from(i).unwrap_or(u8::MAX),
                    )));
                }
                Command::Pending(points)
            }
            Tag::PwmStart => {
                exactly(size::PWM)?;
                let pwm = Pwm {
                    psc: u32_le(data, 0),
                    arr: u32_le(data, 4),
                    ccr1: u32_le(data, 8),
                    pulse_count: u32_le(data, 12) as i32,
                };
                if pwm.psc > 0xFFFF {
                    return Err(out_of_range(Field::Psc));
                }
                if pwm.arr > 0xFFFF {
                    return Err(out_of_range(Field::Arr));
                }
                if pwm.ccr1 > pwm.arr {
                    return Err(out_of_range(Field::Ccr1));
                }
                Command::PwmStart(pwm)
            }
            Tag::UsartStart => {
                let init = match data.len() {
                    size::UART_INIT => UartInit::read(data, false),
                    size::UART_INIT_MANUAL => UartInit::read(data, true),
                    _ => {
                        return Err(bad_len(ExpectedLen::Either(
                            size::UART_INIT,
                            size::UART_INIT_MANUAL,
                        )));
                    }
                };
                if !limits::BAUD_RATE.contains(&init.baud_rate) {
                    return Err(out_of_range(Field::BaudRate));
                }
                Command::UsartStart(init)
            }
            Tag::UsartSend => {
                if data.is_empty() || data.len() > MAX_SERIAL_CHUNK {
                    return Err(bad_len(ExpectedLen::Between(1, MAX_SERIAL_CHUNK)));
                }
                Command::UsartSend(data)
            }
            Tag::ToggleEnablePins => match data.len() {
                0 => Command::ToggleEnablePins { mask: None },
                2 => {
                    let mask = u16_be(data, 0);
                    if mask & !limits::ENABLE_MASK_BITS != 0 {
                        return Err(out_of_range(Field::EnableMask));
                    }
                    Command::ToggleEnablePins { mask: Some(mask) }
                }
                _ => return Err(bad_len(ExpectedLen::Either(0, 2))),
            },
            Tag::SetEnable => {
                exactly(size::SET_ENABLE)?;
                let mask = u16_le(data, 0);
                if mask & !limits::ENABLE_MASK_BITS != 0 {
                    return Err(out_of_range(Field::EnableMask));
                }
                let enable = match u8_at(data, 2) {
                    0 => false,
                    1 => true,
                    _ => return Err(out_of_range(Field::EnableAction)),
                };
                Command::SetEnable { mask, enable }
            }
            Tag::JointsCount => {
                exactly(1)?;
                let joints = u8_at(data, 0);
                if !limits::JOINTS.contains(&joints) {
                    return Err(out_of_range(Field::Joints));
                }
                Command::JointsCount(joints)
            }
            Tag::Location => match data.len() {
                size::LOCATION | size::LOCATION_PACKED => {
                    Command::LocationSetting(Location::read(data))
                }
                _ => {
                    return Err(bad_len(ExpectedLen::Either(
                        size::LOCATION,
                        size::LOCATION_PACKED,
                    )));
                }
            },
            Tag::UploadPeriod => {
                exactly(4)?;
                let period_us = u32_le(data, 0);
                if !limits::UPLOAD_PERIOD_US.contains(&period_us) {
                    return Err(out_of_range(Field::UploadPeriod));
                }
                Command::UploadPeriod { period_us }
            }
            Tag::NetSet => {
                exactly(size::NET_SET)?;
                match NetSettings::read(data) {
                    Some(net) if net.is_valid() => Command::NetSet(net),
                    _ => return Err(out_of_range(Field::NetSettings)),
                }
            }
            // The manual gives STOPPED no data; any is ignored (docs/PROTOCOL.md,
            // section 4): an e-stop is never refused for its length.
            Tag::Stopped => Command::Stopped,
            Tag::Hello => {
                exactly(size::HELLO)?;
                match data.try_into() {
                    Ok(nonce) => Command::Hello { nonce },
                    Err(_) => return Err(bad_len(ExpectedLen::Exactly(size::HELLO))),
                }
            }
            Tag::SetKey => match data.try_into() {
                Ok(key) => Command::SetKey(Some(AuthKey(key))),
                Err(_) if data.is_empty() => Command::SetKey(None),
                Err(_) => return Err(bad_len(ExpectedLen::Either(0, crate::auth::KEY_LEN))),
            },
            // An envelope is opened with `auth::Envelope` before its inner frame is
            // decoded; as a command on its own it is not one.
            Tag::UsartRecv
            | Tag::Ack
            | Tag::DiscoverReply
            | Tag::HelloReply
            | Tag::Auth
            | Tag::Limits
            | Tag::StopCause
            | Tag::RxCounters
            | Tag::Diag
            | Tag::Motion
            | Tag::JointDesc
            | Tag::Homing
            | Tag::Switches => {
                return Err(err(DecodeErrorKind::WrongDirection));
            }
            Tag::LimitsSet => {
                exactly(size::LIMITS_SET)?;
                let set = LimitsSet {
                    joint: u8_at(data, 0),
                    limits: JointLimits::read(data, 4),
                };
                if usize::from(set.joint) >= crate::MAX_JOINTS || !set.limits.is_valid() {
                    return Err(out_of_range(Field::JointLimits));
                }
                Command::LimitsSet(set)
            }
            Tag::AccelSet => {
                exactly(size::ACCEL_SET)?;
                let joint = u8_at(data, 0);
                if usize::from(joint) >= crate::MAX_JOINTS {
                    return Err(out_of_range(Field::JointLimits));
                }
                Command::AccelSet {
                    joint,
                    max_accel_steps_s2: u32_le(data, 4),
                }
            }
            Tag::JointDescSet => {
                exactly(size::JOINT_DESC_SET)?;
                match JointDescSet::read(data) {
                    Some(set) => Command::JointDescSet(set),
                    None => return Err(out_of_range(Field::JointDesc)),
                }
            }
            Tag::Override => {
                exactly(size::OVERRIDE)?;
                let percent = u8_at(data, 0);
                if !(crate::OVERRIDE_MIN_PERCENT..=crate::OVERRIDE_MAX_PERCENT).contains(&percent) {
                    return Err(out_of_range(Field::Override));
                }
                Command::Override { percent }
            }
            Tag::EstopCategory => {
                exactly(size::ESTOP_CATEGORY)?;
                match EStopCategory::from_u8(u8_at(data, 0)) {
                    Some(category) => Command::EstopCategory(category),
                    None => return Err(out_of_range(Field::EstopCategory)),
                }
            }
            Tag::JointDescGet => {
                exactly(size::JOINT_DESC_GET)?;
                let joint = u8_at(data, 0);
                if usize::from(joint) >= crate::MAX_JOINTS {
                    return Err(out_of_range(Field::JointDesc));
                }
                Command::JointDescGet { joint }
            }
            Tag::HomingSet => {
                exactly(size::HOMING_SET)?;
                match HomingSet::read(data) {
                    Some(set) => Command::HomingSet(set),
                    None => return Err(out_of_range(Field::Homing)),
                }
            }
            Tag::HomingGet => {
                exactly(size::HOMING_GET)?;
                let joint = u8_at(data, 0);
                if usize::from(joint) >= crate::MAX_JOINTS {
                    return Err(out_of_range(Field::Homing));
                }
                Command::HomingGet { joint }
            }
            Tag::LimitsGet if data.len() == 1 => match u8_at(data, 0) {
                LIMITS_WITH_ACCEL => Command::LimitsGetWithAccel,
                _ => return Err(out_of_range(Field::LimitsAsk)),
            },
            Tag::Status if data.len() == 1 => match StatusAsk::from_byte(u8_at(data, 0)) {
                Some(ask) => Command::StatusWith(ask),
                None => return Err(out_of_range(Field::StatusAsk)),
            },
            Tag::Runing
            | Tag::UploadStart
            | Tag::UploadStop
            | Tag::PwmStop
            | Tag::UsartStop
            | Tag::Pin0On
            | Tag::Pin0Off
            | Tag::Pin1On
            | Tag::Pin1Off
            | Tag::Return
            | Tag::Status
            | Tag::Discover
            | Tag::EstopReset
            | Tag::Release
            | Tag::Unlock
            | Tag::Hold
            | Tag::Resume
            | Tag::Home
            | Tag::LimitsGet => {
                exactly(0)?;
                match tag {
                    Tag::Runing => Command::Runing,
                    Tag::UploadStart => Command::UploadStart,
                    Tag::UploadStop => Command::UploadStop,
                    Tag::PwmStop => Command::PwmStop,
                    Tag::UsartStop => Command::UsartStop,
                    Tag::Pin0On => Command::Pin0On,
                    Tag::Pin0Off => Command::Pin0Off,
                    Tag::Pin1On => Command::Pin1On,
                    Tag::Pin1Off => Command::Pin1Off,
                    Tag::Return => Command::Return,
                    Tag::Discover => Command::Discover,
                    Tag::EstopReset => Command::EstopReset,
                    Tag::Release => Command::Release,
                    Tag::Unlock => Command::Unlock,
                    Tag::Hold => Command::Hold,
                    Tag::Resume => Command::Resume,
                    Tag::Home => Command::Home,
                    Tag::LimitsGet => Command::LimitsGet,
                    _ => Command::Status,
                }
            }
        };
        Ok(Frame { seq, body })
    }
}
