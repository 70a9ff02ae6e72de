//! The manual's structs and code tables as Rust values, with their wire layout.

use crate::codec::{Writer, i16s, i32_le, i32s, u8_at, u16_le, u32_le};
use crate::{MAX_JOINTS, size};

/// A frame's tag byte: the command or report it carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[repr(u8)]
pub enum Tag {
    /// Start an upload of `count` points.
    New = 0x00,
    /// 1..12 trajectory points.
    Pending = 0x01,
    /// Start executing (the manual's spelling).
    Runing = 0x02,
    /// Stop at once, drop the buffer.
    Stopped = 0x03,
    /// Location reports on.
    UploadStart = 0x04,
    /// Location reports off.
    UploadStop = 0x05,
    /// Gripper PWM on.
    PwmStart = 0x06,
    /// Gripper PWM off.
    PwmStop = 0x07,
    /// Open the pass-through serial port.
    UsartStart = 0x08,
    /// Close it.
    UsartStop = 0x09,
    /// Bytes to write to the serial port.
    UsartSend = 0x0a,
    /// Bytes read from the serial port (controller to host).
    UsartRecv = 0x0b,
    /// GPIO_0 high.
    Pin0On = 0x0c,
    /// GPIO_0 low.
    Pin0Off = 0x0d,
    /// GPIO_1 high.
    Pin1On = 0x0e,
    /// GPIO_1 low.
    Pin1Off = 0x0f,
    /// Toggle driver ENABLE lines.
    ToggleEnablePins = 0x10,
    /// Move every joint to zero.
    Return = 0x11,
    /// Set the number of joints.
    JointsCount = 0x12,
    /// LOCATION_SETTING (host to controller) or LOCATION (controller to host).
    Location = 0x13,
    /// ACK (controller to host).
    Ack = 0x14,
    /// STATUS request or report.
    Status = 0x15,
    /// Location report period.
    UploadPeriod = 0x16,
    /// Who is there? Answered by every controller, from any host (PROTOCOL.md 12).
    Discover = 0x20,
    /// Store the controller's network settings (applied after a reset).
    NetSet = 0x21,
    /// The answer to DISCOVER (controller to host).
    DiscoverReply = 0x22,
}

impl Tag {
    /// The tag for a byte, if there is one.
    pub const fn from_u8(b: u8) -> Option<Tag> {
        use Tag::*;
        Some(match b {
            0x00 => New,
            0x01 => Pending,
            0x02 => Runing,
            0x03 => Stopped,
            0x04 => UploadStart,
            0x05 => UploadStop,
            0x06 => PwmStart,
            0x07 => PwmStop,
            0x08 => UsartStart,
            0x09 => UsartStop,
            0x0a => UsartSend,
            0x0b => UsartRecv,
            0x0c => Pin0On,
            0x0d => Pin0Off,
            0x0e => Pin1On,
            0x0f => Pin1Off,
            0x10 => ToggleEnablePins,
            0x11 => Return,
            0x12 => JointsCount,
            0x13 => Location,
            0x14 => Ack,
            0x15 => Status,
            0x16 => UploadPeriod,
            0x20 => Discover,
            0x21 => NetSet,
            0x22 => DiscoverReply,
            _ => return None,
        })
    }

    /// The manual's name for the command (host direction).
    pub const fn name(self) -> &'static str {
        use Tag::*;
        match self {
            New => "NEW",
            Pending => "PENDING",
            Runing => "RUNING",
            Stopped => "STOPPED",
            UploadStart => "UPLOAD_START",
            UploadStop => "UPLOAD_STOP",
            PwmStart => "PWM_START",
            PwmStop => "PWM_STOP",
            UsartStart => "USART_START",
            UsartStop => "USART_STOP",
            UsartSend => "USART_SEND",
            UsartRecv => "USART_RECV",
            Pin0On => "PIN0_ON",
            Pin0Off => "PIN0_OFF",
            Pin1On => "PIN1_ON",
            Pin1Off => "PIN1_OFF",
            ToggleEnablePins => "TOGGLE_ENABLE_PINS",
            Return => "RETURN",
            JointsCount => "JOINTS_COUNT",
            Location => "LOCATION_SETTING",
            Ack => "ACK",
            Status => "STATUS",
            UploadPeriod => "UPLOAD_PERIOD",
            Discover => "DISCOVER",
            NetSet => "NET_SET",
            DiscoverReply => "DISCOVER_REPLY",
        }
    }
}

/// The trajectory state machine's state, as LOCATION, ACK and STATUS carry it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[repr(u8)]
pub enum State {
    /// NEW arrived; waiting for the first points.
    New = 0,
    /// Points arriving; not moving.
    Pending = 1,
    /// Executing the buffered points.
    Running = 2,
    /// Idle: boot, after a run, after STOPPED.
    #[default]
    Stopped = 3,
}

impl State {
    /// The state for a code, if there is one.
    pub const fn from_u8(b: u8) -> Option<State> {
        match b {
            0 => Some(State::New),
            1 => Some(State::Pending),
            2 => Some(State::Running),
            3 => Some(State::Stopped),
            _ => None,
        }
    }
    /// Upper-case name as in the manual.
    pub const fn name(self) -> &'static str {
        match self {
            State::New => "NEW",
            State::Pending => "PENDING",
            State::Running => "RUNNING",
            State::Stopped => "STOPPED",
        }
    }
}

/// An ACK's status: 0 = done, anything else = the command did nothing.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[repr(u8)]
pub enum StatusCode {
    /// Done.
    Ok = 0,
    /// CRC mismatch; nothing done.
    BadCrc = 1,
    /// No such command.
    UnknownTag = 2,
    /// Data length wrong for the tag.
    BadLength = 3,
    /// Not allowed in the current state.
    BadState = 4,
    /// PENDING seq is not `next_seq`.
    OutOfOrder = 5,
    /// More points than NEW announced.
    TooManyPoints = 6,
    /// A point breaks the trajectory rules (step rate, duration).
    InvalidPoint = 7,
    /// Not enough free buffer slots.
    BufferFull = 8,
    /// Another host owns the controller.
    NotOwner = 9,
    /// Not a command a host may send.
    Unsupported = 10,
    /// A configuration value out of range.
    InvalidConfig = 11,
}

impl StatusCode {
    /// The code for a byte, if there is one.
    pub const fn from_u8(b: u8) -> Option<StatusCode> {
        use StatusCode::*;
        Some(match b {
            0 => Ok,
            1 => BadCrc,
            2 => UnknownTag,
            3 => BadLength,
            4 => BadState,
            5 => OutOfOrder,
            6 => TooManyPoints,
            7 => InvalidPoint,
            8 => BufferFull,
            9 => NotOwner,
            10 => Unsupported,
            11 => InvalidConfig,
            _ => return None,
        })
    }

    /// Name as in docs/PROTOCOL.md, "Status codes (the ACK's `status`)".
    pub const fn name(self) -> &'static str {
        use StatusCode::*;
        match self {
            Ok => "OK",
            BadCrc => "BAD_CRC",
            UnknownTag => "UNKNOWN_TAG",
            BadLength => "BAD_LENGTH",
            BadState => "BAD_STATE",
            OutOfOrder => "OUT_OF_ORDER",
            TooManyPoints => "TOO_MANY_POINTS",
            InvalidPoint => "INVALID_POINT",
            BufferFull => "BUFFER_FULL",
            NotOwner => "NOT_OWNER",
            Unsupported => "UNSUPPORTED",
            InvalidConfig => "INVALID_CONFIG",
        }
    }

    /// What a host should do about it.
    pub const fn advice(self) -> &'static str {
        use StatusCode::*;
        match self {
            Ok => "nothing",
            BadCrc => "the frame was damaged on the way: resend it",
            UnknownTag => "the controller has no such command: check the tag",
            BadLength => "the data length is wrong for this command: check the encoder",
            BadState => {
                "not allowed in the controller's current state: STOP it or wait for the run to end"
            }
            OutOfOrder => "a PENDING frame was lost: resend from the ACK's next_seq",
            TooManyPoints => "more points than NEW announced: send NEW with the right count",
            InvalidPoint => {
                "a point asks for more than the controller's max step rate, or has a duration under 1 us"
            }
            BufferFull => "the trajectory buffer is full: resend when the ACK's `free` allows",
            NotOwner => {
                "another host owns the controller: wait 5 s after it goes quiet, or have it release the arm"
            }
            Unsupported => "this frame only goes from controller to host",
            InvalidConfig => {
                "a value is out of its range (PWM, serial, joint count, point count, upload period)"
            }
        }
    }
}

/// One trajectory segment as the manual's `struct Point` (116 bytes).
///
/// Only `duration` and `position` define the motion; the other arrays are timer hints
/// kept for the vendor's hosts (see [`Point::from_motion`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Point {
    /// Segment length, microseconds (>= 1).
    pub duration: i32,
    /// Hint: `period >> 16` when the period exceeds 16 bits.
    #[cfg_attr(feature = "serde", serde(rename = "numberOfFullPeriod"))]
    pub number_of_full_period: [i16; MAX_JOINTS],
    /// Hint: `period & 0xFFFF` when the period exceeds 16 bits.
    #[cfg_attr(feature = "serde", serde(rename = "restPeriod"))]
    pub rest_period: [i16; MAX_JOINTS],
    /// Hint: the step count N.
    #[cfg_attr(feature = "serde", serde(rename = "numberOfPeriod"))]
    pub number_of_period: [i16; MAX_JOINTS],
    /// Hint: `floor(duration / N)` microseconds.
    pub period: [i32; MAX_JOINTS],
    /// Absolute joint positions in steps at the end of the segment.
    pub position: [i32; MAX_JOINTS],
}

impl Point {
    /// A point of `duration_us` that moves from `previous` to `target`, with the timer
    /// hints filled as docs/PROTOCOL.md's "Point (116 bytes)" says (`numberOfPeriod` = N
    /// truncated to 16 bits, `period` = floor(duration / N), the split when it exceeds 16 bits).
    pub fn from_motion(
        duration_us: i32,
        previous: &[i32; MAX_JOINTS],
        target: &[i32; MAX_JOINTS],
    ) -> Point {
        let mut p = Point {
            duration: duration_us,
            position: *target,
            ..Point::default()
        };
        for j in 0..MAX_JOINTS {
            let steps = (i64::from(target[j]) - i64::from(previous[j])).unsigned_abs();
            if steps == 0 {
                continue;
            }
            let period = (i64::from(duration_us.max(0)) as u64 / steps) as u32;
            p.number_of_period[j] = steps as u16 as i16;
            p.period[j] = period as i32;
            if period > 0xFFFF {
                p.number_of_full_period[j] = (period >> 16) as u16 as i16;
                p.rest_period[j] = (period & 0xFFFF) as u16 as i16;
            }
        }
        p
    }

    /// Steps joint `j` makes in this segment after `previous`, signed.
    ///
    /// # Panics
    /// If `j >= MAX_JOINTS` (a caller's bug, never a value from the network).
    pub fn steps(&self, previous: &[i32; MAX_JOINTS], j: usize) -> i64 {
        i64::from(self.position[j]) - i64::from(previous[j])
    }

    pub(crate) fn read(b: &[u8]) -> Point {
        Point {
            duration: i32_le(b, 0),
            number_of_full_period: i16s(b, 4),
            rest_period: i16s(b, 20),
            number_of_period: i16s(b, 36),
            period: i32s(b, 52),
            position: i32s(b, 84),
        }
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>, at: usize) {
        w.u32(at, self.duration as u32);
        w.i16s(at + 4, &self.number_of_full_period);
        w.i16s(at + 20, &self.rest_period);
        w.i16s(at + 36, &self.number_of_period);
        w.i32s(at + 52, &self.period);
        w.i32s(at + 84, &self.position);
    }
}

/// Joint positions (steps) and, in reports, the state (`struct Location`, 36 bytes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Location {
    /// Position of each joint in steps.
    pub position: [i32; MAX_JOINTS],
    /// State code (reports); ignored in LOCATION_SETTING.
    pub state: u8,
}

impl Location {
    pub(crate) fn read(b: &[u8]) -> Location {
        Location {
            position: i32s(b, 0),
            state: u8_at(b, 32),
        }
    }
    pub(crate) fn write(&self, w: &mut Writer<'_>, at: usize) {
        w.i32s(at, &self.position);
        w.u8(at + 32, self.state);
        w.put(at + 33, &[0, 0, 0]);
    }
}

/// Gripper timer registers (`struct Pwm`, 16 bytes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Pwm {
    /// Prescaler, 0..=0xFFFF.
    pub psc: u32,
    /// Auto-reload, 0..=0xFFFF.
    pub arr: u32,
    /// Compare value, <= ARR.
    pub ccr1: u32,
    /// 0: servo mode; else stepper mode, |n| pulses in the direction of the sign.
    pub pulse_count: i32,
}

impl Pwm {
    /// Output frequency for a timer input clock.
    pub fn frequency_hz(&self, timer_clock_hz: u32) -> f64 {
        f64::from(timer_clock_hz) / ((f64::from(self.psc) + 1.0) * (f64::from(self.arr) + 1.0))
    }
    /// High time as a fraction of the period.
    pub fn duty(&self) -> f64 {
        f64::from(self.ccr1) / (f64::from(self.arr) + 1.0)
    }
    /// One PWM period in timer-clock ticks.
    pub fn period_ticks(&self) -> u64 {
        (u64::from(self.psc) + 1) * (u64::from(self.arr) + 1)
    }
}

/// Serial port settings (`UART_InitTypeDef`, 28 bytes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct UartInit {
    /// Baud rate, 300..=4_000_000.
    pub baud_rate: u32,
    /// STM32 HAL value (0 = 8 bits).
    pub word_length: u32,
    /// STM32 HAL value (0 = 1 stop bit).
    pub stop_bits: u32,
    /// STM32 HAL value (0 = none).
    pub parity: u32,
    /// 0 = transmit and receive, 1 = receive only, 2 = transmit only, else both.
    pub mode: u32,
    /// STM32 HAL value (0 = none).
    pub hw_flow_ctl: u32,
    /// STM32 HAL value (0 = 16).
    pub over_sampling: u32,
}

/// Which directions the serial pass-through carries.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum UartMode {
    /// Both directions.
    TransmitReceive,
    /// Peripheral to host only: USART_SEND is refused.
    ReceiveOnly,
    /// Host to peripheral only: nothing is read.
    TransmitOnly,
}

impl UartInit {
    /// The `Mode` field as the manual defines it (unknown values mean both directions).
    pub fn mode(&self) -> UartMode {
        match self.mode {
            1 => UartMode::ReceiveOnly,
            2 => UartMode::TransmitOnly,
            _ => UartMode::TransmitReceive,
        }
    }
    /// Bits on the line per byte: start + data + parity + stop, from the HAL codes.
    pub fn bits_per_byte(&self) -> u32 {
        // HAL: WordLength 0 = 8 bits, 0x1000 = 9 bits (F4); parity adds no bit in the
        // HAL's framing (it replaces the MSB); StopBits 0x2000 = 2 stop bits.
        let data = if self.word_length == 0x1000 { 9 } else { 8 };
        let stop = if self.stop_bits == 0x2000 { 2 } else { 1 };
        1 + data + stop
    }
    pub(crate) fn read(b: &[u8], manual_form: bool) -> UartInit {
        // The manual's form repeats `Parity`: the second word is skipped.
        let skip = if manual_form { 4 } else { 0 };
        UartInit {
            baud_rate: u32_le(b, 0),
            word_length: u32_le(b, 4),
            stop_bits: u32_le(b, 8),
            parity: u32_le(b, 12),
            mode: u32_le(b, 16 + skip),
            hw_flow_ctl: u32_le(b, 20 + skip),
            over_sampling: u32_le(b, 24 + skip),
        }
    }
    pub(crate) fn write(&self, w: &mut Writer<'_>, at: usize) {
        for (i, v) in [
            self.baud_rate,
            self.word_length,
            self.stop_bits,
            self.parity,
            self.mode,
            self.hw_flow_ctl,
            self.over_sampling,
        ]
        .into_iter()
        .enumerate()
        {
            w.u32(at + 4 * i, v);
        }
    }
}

/// The controller's reply to every command with a valid CRC (and to a bad CRC).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Ack {
    /// Tag of the command answered.
    pub acked_tag: u8,
    /// What became of it.
    pub status: StatusCode,
    /// State after the command.
    pub state: State,
    /// The seq the controller expects next during an upload.
    pub next_seq: u8,
    /// Trajectory points held (received, not yet run).
    pub buffered: u16,
    /// Free trajectory slots.
    pub free: u16,
}

impl Ack {
    pub(crate) fn write(&self, w: &mut Writer<'_>, at: usize) {
        w.u8(at, self.acked_tag);
        w.u8(at + 1, self.status as u8);
        w.u8(at + 2, self.state as u8);
        w.u8(at + 3, self.next_seq);
        w.u16(at + 4, self.buffered);
        w.u16(at + 6, self.free);
    }
}

/// STATUS `flags` bits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct StatusFlags(pub u8);

impl StatusFlags {
    /// Location reports on.
    pub const REPORTS_ON: u8 = 1 << 0;
    /// Drivers enabled (any ENABLE line active).
    pub const DRIVERS_ENABLED: u8 = 1 << 1;
    /// Serial pass-through open.
    pub const SERIAL_OPEN: u8 = 1 << 2;
    /// PIN0 high.
    pub const PIN0_HIGH: u8 = 1 << 3;
    /// PIN1 high.
    pub const PIN1_HIGH: u8 = 1 << 4;
    /// The last run ended by buffer underrun.
    pub const UNDERRUN: u8 = 1 << 5;
    /// Gripper PWM active.
    pub const PWM_ACTIVE: u8 = 1 << 6;
    /// The last run ended by STOPPED.
    pub const STOPPED_BY_HOST: u8 = 1 << 7;

    /// Whether every bit of `bits` is set.
    pub const fn has(self, bits: u8) -> bool {
        self.0 & bits == bits
    }
    /// Sets or clears `bits`.
    pub fn set(&mut self, bits: u8, on: bool) {
        if on {
            self.0 |= bits;
        } else {
            self.0 &= !bits;
        }
    }
}

/// STATUS `more_flags` bits (offset 18; an old controller sends 0).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct MoreFlags(pub u16);

impl MoreFlags {
    /// An upload not yet running (state NEW or PENDING) was dropped when another host
    /// took the controller over after the owner's 5 s of silence. Cleared by the next NEW.
    pub const UPLOAD_DROPPED: u16 = 1 << 0;

    /// Whether every bit of `bits` is set.
    pub const fn has(self, bits: u16) -> bool {
        self.0 & bits == bits
    }
    /// Sets or clears `bits`.
    pub fn set(&mut self, bits: u16, on: bool) {
        if on {
            self.0 |= bits;
        } else {
            self.0 &= !bits;
        }
    }
}

/// The window a host may assume when STATUS `window` is 0 (a controller from before the
/// field existed took bursts of 8 datagrams).
pub const DEFAULT_WINDOW: u16 = 8;

/// The STATUS report (36 bytes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct StatusReport {
    /// Firmware protocol version: major, minor, patch.
    pub version: [u8; 3],
    /// Joints in use.
    pub joints: u8,
    /// Current state.
    pub state: State,
    /// See [`StatusFlags`].
    pub flags: StatusFlags,
    /// Datagrams the controller takes back to back without dropping one (the window a
    /// host may keep in flight); 0 from an old controller: assume [`DEFAULT_WINDOW`].
    pub window: u16,
    /// Points held (received, not yet run).
    pub buffered: u16,
    /// Points NEW announced.
    pub expected: u16,
    /// Points of the current trajectory received.
    pub received: u16,
    /// Points of the current trajectory run.
    pub executed: u16,
    /// Trajectory buffer size in points.
    pub capacity: u16,
    /// See [`MoreFlags`].
    pub more_flags: MoreFlags,
    /// Location report period, microseconds.
    pub upload_period_us: u32,
    /// Input clock of the gripper timer.
    pub pwm_timer_clock_hz: u32,
    /// Highest step rate of one joint.
    pub max_step_rate_hz: u32,
    /// Most steps per second over all joints together that the controller takes on
    /// (offset 32; 0 from a controller that predates it: no limit stated). Points
    /// asking for more are refused with INVALID_POINT (docs/PROTOCOL.md).
    pub step_budget_hz: u32,
}

impl StatusReport {
    pub(crate) fn read(b: &[u8]) -> Option<StatusReport> {
        Some(StatusReport {
            version: [u8_at(b, 0), u8_at(b, 1), u8_at(b, 2)],
            joints: u8_at(b, 3),
            state: State::from_u8(u8_at(b, 4))?,
            flags: StatusFlags(u8_at(b, 5)),
            window: u16_le(b, 6),
            buffered: u16_le(b, 8),
            expected: u16_le(b, 10),
            received: u16_le(b, 12),
            executed: u16_le(b, 14),
            capacity: u16_le(b, 16),
            more_flags: MoreFlags(u16_le(b, 18)),
            upload_period_us: u32_le(b, 20),
            pwm_timer_clock_hz: u32_le(b, 24),
            max_step_rate_hz: u32_le(b, 28),
            step_budget_hz: u32_le(b, 32),
        })
    }
    pub(crate) fn write(&self, w: &mut Writer<'_>, at: usize) {
        w.put(at, &self.version);
        w.u8(at + 3, self.joints);
        w.u8(at + 4, self.state as u8);
        w.u8(at + 5, self.flags.0);
        w.u16(at + 6, self.window);
        w.u16(at + 8, self.buffered);
        w.u16(at + 10, self.expected);
        w.u16(at + 12, self.received);
        w.u16(at + 14, self.executed);
        w.u16(at + 16, self.capacity);
        w.u16(at + 18, self.more_flags.0);
        w.u32(at + 20, self.upload_period_us);
        w.u32(at + 24, self.pwm_timer_clock_hz);
        w.u32(at + 28, self.max_step_rate_hz);
        w.u32(at + 32, self.step_budget_hz);
    }
}

const _: () = assert!(size::POINT == 4 + 3 * 16 + 2 * 32);
