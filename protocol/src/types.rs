//! The manual's structs and code tables as Rust values, with their wire layout.

use crate::codec::{Writer, i16s, i32_le, i32s, u8_at, u16_le, u32_le};
use crate::codes::{State, StatusCode};
use crate::{MAX_JOINTS, size};

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
        let hints = (p.number_of_period.iter_mut().zip(&mut p.period))
            .zip(p.number_of_full_period.iter_mut().zip(&mut p.rest_period));
        for ((from, to), ((count, period_hint), (full, rest))) in
            previous.iter().zip(target).zip(hints)
        {
            let steps = (i64::from(*to) - i64::from(*from)).unsigned_abs();
            if steps == 0 {
                continue;
            }
            // duration_us / steps <= i32::MAX.
            let period = u32::try_from(i64::from(duration_us.max(0)).unsigned_abs() / steps)
                .unwrap_or(u32::MAX);
            *count = low_16(steps);
            *period_hint = period as i32;
            if period > 0xFFFF {
                *full = low_16(u64::from(period >> 16));
                *rest = low_16(u64::from(period));
            }
        }
        p
    }

    /// Steps joint `j` makes in this segment after `previous`, signed.
    ///
    /// # Panics
    /// If `j >= MAX_JOINTS` (a caller's bug, never a value from the network).
    #[allow(
        clippy::indexing_slicing,
        reason = "documented: j >= MAX_JOINTS is the caller's bug"
    )]
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

/// The low 16 bits, as the manual's `int16_t` hints hold a count or period that may not
/// fit them.
#[allow(
    clippy::cast_possible_truncation,
    reason = "truncation to 16 bits is the hint's definition"
)]
fn low_16(v: u64) -> i16 {
    v as u16 as i16
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

/// `has` and `set` of a bit-set field (`StatusFlags`, `MoreFlags`).
macro_rules! flag_bits {
    ($flags:ident, $bits:ty) => {
        impl $flags {
            /// Whether every bit of `bits` is set.
            pub const fn has(self, bits: $bits) -> bool {
                self.0 & bits == bits
            }
            /// Sets or clears `bits`.
            pub fn set(&mut self, bits: $bits, on: bool) {
                if on {
                    self.0 |= bits;
                } else {
                    self.0 &= !bits;
                }
            }
        }
    };
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
}

flag_bits!(StatusFlags, u8);

/// STATUS `more_flags` bits (offset 18; an old controller sends 0).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct MoreFlags(pub u16);

impl MoreFlags {
    /// An upload not yet running (state NEW or PENDING) was dropped when another host
    /// took the controller over after the owner's 5 s of silence. Cleared by the next NEW.
    pub const UPLOAD_DROPPED: u16 = 1 << 0;
    /// The wired e-stop input is open now (always 0 on a controller without one).
    pub const ESTOP_OPEN: u16 = 1 << 1;
    /// The wired e-stop input has opened since its latch was last cleared: RUNING and
    /// RETURN are refused with `ESTOP_LATCHED` until the input is closed and a host sends
    /// ESTOP_RESET.
    pub const ESTOP_LATCHED: u16 = 1 << 2;
    /// This controller reports each driver's ENABLE: bit 4 the gripper's and bits 8-15
    /// joints 0-7 (issue 23). Clear from an older controller, whose bits 4 and 8-15 are 0
    /// and mean nothing: [`StatusReport::drivers_enabled`] is `None` then.
    pub const ENABLES_REPORTED: u16 = 1 << 3;
    /// The gripper driver is enabled (with [`MoreFlags::ENABLES_REPORTED`]).
    pub const GRIPPER_ENABLED: u16 = 1 << 4;
    /// Shift of the joints' ENABLE bits: joint j is bit `JOINTS_ENABLED_SHIFT + j`.
    pub const JOINTS_ENABLED_SHIFT: u32 = 8;
    /// Bits 5-7: what ended the last run, a [`crate::StopCause`] byte (issue 31); 0 from
    /// an older controller (not reported).
    pub const STOP_CAUSE_MASK: u16 = 0b111 << Self::STOP_CAUSE_SHIFT;
    /// Shift of [`MoreFlags::STOP_CAUSE_MASK`].
    pub const STOP_CAUSE_SHIFT: u32 = 5;

    /// The bits that report `cause`.
    pub const fn of_stop_cause(cause: crate::StopCause) -> u16 {
        ((cause as u16) << Self::STOP_CAUSE_SHIFT) & Self::STOP_CAUSE_MASK
    }

    /// The bits that report `enabled` (bits 0-7 joints, bit 8 gripper, as the ENABLE
    /// masks), [`MoreFlags::ENABLES_REPORTED`] included.
    pub const fn of_enabled(enabled: u16) -> u16 {
        let gripper = if enabled & 0x100 != 0 {
            Self::GRIPPER_ENABLED
        } else {
            0
        };
        Self::ENABLES_REPORTED | gripper | ((enabled & 0xFF) << Self::JOINTS_ENABLED_SHIFT)
    }
}

flag_bits!(MoreFlags, u16);

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
    /// host may keep in flight); 0 from an old controller: assume
    /// [`DEFAULT_WINDOW`](crate::limits::DEFAULT_WINDOW).
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
    /// Each driver's ENABLE (bits 0-7 joints, bit 8 gripper, as the ENABLE masks), from
    /// `more_flags`; `None` from a controller that does not report them (bit 3 clear:
    /// only `flags` bit 1, "any driver enabled", is known then).
    pub const fn drivers_enabled(&self) -> Option<u16> {
        let m = self.more_flags.0;
        if m & MoreFlags::ENABLES_REPORTED == 0 {
            return None;
        }
        let gripper = if m & MoreFlags::GRIPPER_ENABLED != 0 {
            0x100
        } else {
            0
        };
        Some(gripper | (m >> MoreFlags::JOINTS_ENABLED_SHIFT))
    }

    /// What ended the last run (`more_flags` bits 5-7, issue 31); `None` from a
    /// controller that does not report it (bits 5-7 all 0): then only `flags` bits 5
    /// (underrun) and 7 (STOPPED, or the wired e-stop input) are known.
    pub const fn stop_cause(&self) -> Option<crate::StopCause> {
        let byte = (self.more_flags.0 & MoreFlags::STOP_CAUSE_MASK) >> MoreFlags::STOP_CAUSE_SHIFT;
        crate::StopCause::from_u8(byte as u8)
    }

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
