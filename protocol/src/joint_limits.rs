//! Limits on the controller (issue 23): each joint's position range and step rate, set
//! with LIMITS_SET and read with LIMITS_GET (answered with a LIMITS report, which also
//! names the last point refused and why: docs/PROTOCOL.md, "LIMITS_SET, LIMITS_GET").

use crate::MAX_JOINTS;
use crate::codec::{Writer, i32_le, u8_at, u32_le};

/// One joint's limits (12 bytes on the wire: min, max, max_rate_hz).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct JointLimits {
    /// Lowest position a point may end at, steps.
    pub min: i32,
    /// Highest position a point may end at, steps (`min <= max`).
    pub max: i32,
    /// Most steps per second of this joint; 0: none of its own (the controller's
    /// `max_step_rate_hz` applies, as it always does).
    pub max_rate_hz: u32,
}

impl JointLimits {
    /// No limit: the whole i32 range, no rate of its own (the boot default).
    pub const NONE: JointLimits = JointLimits {
        min: i32::MIN,
        max: i32::MAX,
        max_rate_hz: 0,
    };

    /// Whether the limits can be met (`min <= max`).
    pub const fn is_valid(&self) -> bool {
        self.min <= self.max
    }

    /// Whether `position` is inside the range.
    pub const fn contains(&self, position: i32) -> bool {
        self.min <= position && position <= self.max
    }

    /// The rate a joint may step at on a controller whose own limit is `board_hz`.
    pub fn rate_hz(&self, board_hz: u32) -> u32 {
        if self.max_rate_hz == 0 {
            board_hz
        } else {
            self.max_rate_hz.min(board_hz)
        }
    }

    pub(crate) fn read(b: &[u8], at: usize) -> JointLimits {
        JointLimits {
            min: i32_le(b, at),
            max: i32_le(b, at + 4),
            max_rate_hz: u32_le(b, at + 8),
        }
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>, at: usize) {
        w.u32(at, self.min as u32);
        w.u32(at + 4, self.max as u32);
        w.u32(at + 8, self.max_rate_hz);
    }
}

impl Default for JointLimits {
    fn default() -> Self {
        Self::NONE
    }
}

/// Why a point (or RETURN, or LOCATION_SETTING) was refused with INVALID_POINT.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[repr(u8)]
pub enum RefusalReason {
    /// Nothing refused since boot.
    #[default]
    None = 0,
    /// The position is below the joint's `min` (`limit`).
    BelowMin = 1,
    /// The position is above the joint's `max` (`limit`).
    AboveMax = 2,
    /// The joint's steps per second (`value`) exceed its own `max_rate_hz` (`limit`).
    JointRate = 3,
    /// The joint's steps per second exceed the controller's `max_step_rate_hz`.
    BoardRate = 4,
    /// All joints' steps per second together exceed `step_budget_hz` (`joint` is 0xFF).
    StepBudget = 5,
    /// The point's duration is under 1 us (`value`), or its step count does not fit.
    Duration = 6,
    /// The change of the joint's rate between two consecutive segments exceeds its
    /// `max_accel_steps_s2` (ACCEL_SET, issue 31; `value` the acceleration asked, `limit`
    /// the most). docs/PROTOCOL.md, ACCEL_SET, defines it.
    Acceleration = 8,
    /// The point moves a joint whose driver is disabled (limp, SET_ENABLE or
    /// TOGGLE_ENABLE_PINS): its steps would go to a driver that ignores them while the
    /// controller counts them (issue 31). `value` is the position asked, `limit` where the
    /// joint is.
    JointDisabled = 7,
}

impl RefusalReason {
    /// The reason of a byte (unknown bytes: `None`, as from a newer controller).
    pub const fn from_u8(b: u8) -> RefusalReason {
        match b {
            1 => RefusalReason::BelowMin,
            2 => RefusalReason::AboveMax,
            3 => RefusalReason::JointRate,
            4 => RefusalReason::BoardRate,
            5 => RefusalReason::StepBudget,
            6 => RefusalReason::Duration,
            7 => RefusalReason::JointDisabled,
            8 => RefusalReason::Acceleration,
            _ => RefusalReason::None,
        }
    }

    /// What it means, for a person.
    pub const fn describe(self) -> &'static str {
        match self {
            RefusalReason::None => "nothing refused",
            RefusalReason::BelowMin => "position below the joint's min",
            RefusalReason::AboveMax => "position above the joint's max",
            RefusalReason::JointRate => "steps/s above the joint's max rate",
            RefusalReason::BoardRate => "steps/s above the controller's max_step_rate_hz",
            RefusalReason::StepBudget => "steps/s of all joints above step_budget_hz",
            RefusalReason::Duration => "duration under 1 us or too many steps",
            RefusalReason::JointDisabled => "moves a joint whose driver is disabled (limp)",
            RefusalReason::Acceleration => "steps/s² above the joint's max acceleration",
        }
    }
}

/// The last INVALID_POINT refusal of a limit, as the LIMITS report gives it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct Refusal {
    /// The refused frame's seq.
    pub seq: u8,
    /// Its tag (PENDING, RETURN, LOCATION_SETTING).
    pub tag: u8,
    /// The point's index in the PENDING frame (0 for RETURN and LOCATION_SETTING).
    pub point: u8,
    /// The joint (0xFF: all joints together, the step budget).
    pub joint: u8,
    /// Why.
    pub reason: RefusalReason,
    /// The value refused: a position in steps, or steps per second (saturated).
    pub value: i32,
    /// The limit it broke (steps, or steps per second).
    pub limit: i32,
}

/// The LIMITS report (112 bytes): every joint's limits, then the last refusal.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct LimitsReport {
    /// Joints 0-7.
    pub joints: [JointLimits; MAX_JOINTS],
    /// The last point refused for a limit since boot (`reason` None: none).
    pub last_refusal: Refusal,
    /// Each joint's `max_accel_steps_s2` (ACCEL_SET; 0: none), when LIMITS_GET asked for
    /// them (issue 31: 32 more bytes); `None`: the 112-byte report of old hosts.
    pub max_accel: Option<[u32; MAX_JOINTS]>,
}

impl LimitsReport {
    pub(crate) fn read(b: &[u8]) -> LimitsReport {
        let mut joints = [JointLimits::NONE; MAX_JOINTS];
        for (j, l) in joints.iter_mut().enumerate() {
            *l = JointLimits::read(b, 12 * j);
        }
        let at = 12 * MAX_JOINTS;
        LimitsReport {
            joints,
            last_refusal: Refusal {
                seq: u8_at(b, at),
                tag: u8_at(b, at + 1),
                point: u8_at(b, at + 2),
                joint: u8_at(b, at + 3),
                reason: RefusalReason::from_u8(u8_at(b, at + 4)),
                value: i32_le(b, at + 8),
                limit: i32_le(b, at + 12),
            },
            max_accel: (b.len() >= crate::size::LIMITS_WITH_ACCEL).then(|| {
                let mut accel = [0u32; MAX_JOINTS];
                for (j, a) in accel.iter_mut().enumerate() {
                    *a = u32_le(b, crate::size::LIMITS + 4 * j);
                }
                accel
            }),
        }
    }

    /// Bytes of data: with the accelerations or without.
    pub fn data_len(&self) -> usize {
        if self.max_accel.is_some() {
            crate::size::LIMITS_WITH_ACCEL
        } else {
            crate::size::LIMITS
        }
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>, at: usize) {
        for (j, l) in self.joints.iter().enumerate() {
            l.write(w, at + 12 * j);
        }
        let r = &self.last_refusal;
        let at = at + 12 * MAX_JOINTS;
        w.put(
            at,
            &[r.seq, r.tag, r.point, r.joint, r.reason as u8, 0, 0, 0],
        );
        w.u32(at + 8, r.value as u32);
        w.u32(at + 12, r.limit as u32);
        if let Some(accel) = self.max_accel {
            for (j, a) in accel.iter().enumerate() {
                w.u32(at + 16 + 4 * j, *a);
            }
        }
    }
}

/// LIMITS_SET's data: one joint's limits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct LimitsSet {
    /// The joint, 0-7.
    pub joint: u8,
    /// Its new limits.
    pub limits: JointLimits,
}
