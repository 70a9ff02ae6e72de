//! HOLD, RESUME, OVERRIDE and the MOTION report (issue 32): motion control in flight as a
//! time warp of what remains (arm-step's `Warp`: every joint on one time scale, so the
//! path is kept; how many steps come is never changed, so every joint still ends exactly on
//! its last point). MOTION is a report of its own, asked for with STATUS's request byte
//! bit 4: the 36-byte STATUS report is full, and every host decodes it as exactly that.

use crate::codec::{Writer, u8_at, u16_le};

/// Override percent (OVERRIDE's byte, MOTION's factor): the lowest accepted.
pub const OVERRIDE_MIN_PERCENT: u8 = 1;

/// The highest: 200 % (arm-step's `MAX_RATE`); above 100 % only where every joint's rate
/// and acceleration allow (else refused `OVERRIDE_REFUSED`, MOTION names the joint).
pub const OVERRIDE_MAX_PERCENT: u8 = 200;

crate::codes::wire_code! {
    /// Which limit an override above 100 % would break (MOTION's refusal).
    pub enum OverrideLimit {
        /// A joint's most step rate (LIMITS' `max_rate_hz`, or the controller's).
        Rate = 1 => "RATE",
        /// A joint's most acceleration (ACCEL_SET's `max_accel_steps_s2`).
        Accel = 2 => "ACCEL",
        /// The step side's budget for warped steps (issue 32: all joints' steps per second
        /// under a warp, `BoardProfile::warp_budget_hz`): the whole run, joint 0xFF. Also
        /// for a HOLD refused `OVERRIDE_REFUSED` and a RUNING at a factor other than 100 %.
        StepBudget = 3 => "STEP_BUDGET",
    }
}

crate::codes::wire_code! {
    /// What the last controlled stop was (MOTION byte 4).
    pub enum ControlledStop {
        /// None since boot (or since the last run started).
        None = 0 => "NONE",
        /// A HOLD: the run decelerated to a standstill and waits for RESUME.
        Hold = 1 => "HOLD",
        /// An underrun with enough path buffered (issue 32): the run slowed along what
        /// it held, within the accelerations, and ended STOPPED (cause UNDERRUN, detail 1)
        /// at the last point it had. A dead underrun (too little path, or no ACCEL_SET
        /// limit) does not change this byte: STOP_CAUSE's detail 0 says it.
        Underrun = 2 => "UNDERRUN",
        /// The safety door opened (issue 32): the run held; close it, then RESUME.
        Door = 3 => "DOOR",
        /// The wired e-stop input opened under category 1 (issue 32): the run
        /// decelerated along its path, then stopped latched with the drivers disabled.
        EStop = 4 => "ESTOP",
    }
}

crate::codes::wire_code! {
    /// How the wired e-stop input stops the arm (ESTOP_CATEGORY's byte, MOTION's byte 7;
    /// IEC 60204-1's stop categories). Either way the controller ends latched STOPPED
    /// (RUNING and RETURN refused until the input is closed and a host sends ESTOP_RESET).
    #[derive(Default)]
    pub enum EStopCategory {
        /// Every STEP output stops at once, in the input's interrupt (the default, and
        /// what an older controller does).
        #[default]
        Instant = 0 => "CATEGORY_0",
        /// A controlled stop: the run decelerates along its path within every joint's
        /// acceleration, then the drivers are disabled. Within a bound
        /// (PROTOCOL.md, "Wired e-stop input"), else, and on a step side without a time
        /// warp, the stop is category 0's.
        Controlled = 1 => "CATEGORY_1",
    }
}

/// MOTION's flags byte.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct MotionFlags(pub u8);

impl MotionFlags {
    /// A HOLD is in force (RUNNING with the held flag): decelerating or at rest.
    pub const HELD: u8 = 1 << 0;
    /// The run stands still (the warp's rate is 0).
    pub const AT_REST: u8 = 1 << 1;
    /// The rate is changing (a hold, a resume or an override ramping).
    pub const RAMPING: u8 = 1 << 2;
    /// The host is late (issue 32): the run is slowing along what it holds to the
    /// underrun creep, and goes back to the override when enough points arrive.
    pub const UNDERRUN_RAMP: u8 = 1 << 3;
    /// The safety door is open (issue 32): runs hold, RUNING and RESUME are refused
    /// `DOOR_OPEN`. Shown in any state.
    pub const DOOR_OPEN: u8 = 1 << 4;
    /// The wired e-stop input opened under category 1 (issue 32): the run is
    /// decelerating to a standstill, after which the drivers are disabled and the
    /// controller is latched STOPPED.
    pub const ESTOP_RAMP: u8 = 1 << 5;

    /// Whether every bit of `bits` is set.
    pub const fn has(self, bits: u8) -> bool {
        self.0 & bits == bits
    }
}

/// The MOTION report (8 bytes), the answer to STATUS's request byte bit 4.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct MotionReport {
    /// The override in force, percent (1..200; 100 when no host sent OVERRIDE): the one
    /// asked for, or lower where a point that arrived after it lowered it (issue 32).
    pub factor_percent: u8,
    /// Held, at rest, ramping.
    pub flags: MotionFlags,
    /// The rate now, tenths of a percent (0..2000): below the factor while ramping, 0 at
    /// rest.
    pub rate_permille: u16,
    /// What the last controlled stop was (`None`: a byte this crate does not know).
    pub last_stop: Option<ControlledStop>,
    /// The last OVERRIDE refused: the joint (0-7; 0xFF none).
    pub refused_joint: u8,
    /// ... and the limit it would have broken (`None`: none, or a byte this crate does
    /// not know).
    pub refused_limit: Option<OverrideLimit>,
    /// The wired e-stop input's stop category (byte 7; an older controller sends 0,
    /// which is what it does). `None`: a byte this crate does not know.
    pub estop_category: Option<EStopCategory>,
}

impl MotionReport {
    /// No override, no hold: what a controller that never got the new frames reports.
    pub const IDLE: MotionReport = MotionReport {
        factor_percent: 100,
        flags: MotionFlags(0),
        rate_permille: 1000,
        last_stop: Some(ControlledStop::None),
        refused_joint: 0xFF,
        refused_limit: None,
        estop_category: Some(EStopCategory::Instant),
    };

    pub(crate) fn read(b: &[u8]) -> MotionReport {
        MotionReport {
            factor_percent: u8_at(b, 0),
            flags: MotionFlags(u8_at(b, 1)),
            rate_permille: u16_le(b, 2),
            last_stop: ControlledStop::from_u8(u8_at(b, 4)),
            refused_joint: u8_at(b, 5),
            refused_limit: OverrideLimit::from_u8(u8_at(b, 6)),
            estop_category: EStopCategory::from_u8(u8_at(b, 7)),
        }
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>, at: usize) {
        w.u8(at, self.factor_percent);
        w.u8(at + 1, self.flags.0);
        w.u16(at + 2, self.rate_permille);
        w.u8(at + 4, self.last_stop.map_or(0, |s| s as u8));
        w.u8(at + 5, self.refused_joint);
        w.u8(at + 6, self.refused_limit.map_or(0, |l| l as u8));
        w.u8(at + 7, self.estop_category.map_or(0, |c| c as u8));
    }
}
