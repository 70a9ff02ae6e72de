//! Homing on switches (issue 33): HOMING_SET (0x2d) and the HOMING report (0x2f) carry one
//! joint's homing settings ([`HomingSet`]); the SWITCHES report (0x30, asked for by bit 5
//! of STATUS's request byte) the homing cycle's progress and the switch inputs
//! ([`SwitchesReport`]). A report of its own: STATUS's 36 bytes are full.

use crate::codec::{Writer, u8_at, u32_le};

/// One joint's homing settings (docs/PROTOCOL.md, HOMING_SET): kept across power cycles
/// with the joint's limits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct HomingSettings {
    /// Whether HOME homes this joint on its home switch.
    pub enabled: bool,
    /// The switch is on the max side (the seek moves positive); else the min side.
    pub towards_max: bool,
    /// The home switch is also this side's limit switch (its trips do not stop the arm
    /// while this joint homes).
    pub switch_is_limit: bool,
    /// Joints home in increasing order (ties: lower joint first).
    pub order: u8,
    /// Seek rate, steps/s (> 0 when enabled).
    pub seek_rate_hz: u32,
    /// Back-off and slow approach rate, steps/s (> 0 when enabled).
    pub approach_rate_hz: u32,
    /// Back-off, steps (> 0 when enabled).
    pub backoff_steps: u32,
    /// Longest seek, steps (> 0 when enabled): past it the cycle fails naming the joint.
    pub max_travel_steps: u32,
    /// The joint's count at the switch's closing point once homed.
    pub offset: i32,
}

impl HomingSettings {
    /// Not homed on a switch (the default, and what settings stored before it load with).
    pub const NONE: HomingSettings = HomingSettings {
        enabled: false,
        towards_max: false,
        switch_is_limit: false,
        order: 0,
        seek_rate_hz: 0,
        approach_rate_hz: 0,
        backoff_steps: 0,
        max_travel_steps: 0,
        offset: 0,
    };

    /// Flags byte: bit 0 enabled, bit 1 towards max, bit 2 switch is the limit.
    const ENABLED: u8 = 1 << 0;
    const TOWARDS_MAX: u8 = 1 << 1;
    const SWITCH_IS_LIMIT: u8 = 1 << 2;

    /// Whether the settings can be run: a joint not enabled always; an enabled one with
    /// every rate, the back-off and the travel non-zero.
    pub const fn is_valid(&self) -> bool {
        !self.enabled
            || (self.seek_rate_hz > 0
                && self.approach_rate_hz > 0
                && self.backoff_steps > 0
                && self.max_travel_steps > 0)
    }

    /// The flags byte.
    pub const fn flags(&self) -> u8 {
        (if self.enabled { Self::ENABLED } else { 0 })
            | (if self.towards_max {
                Self::TOWARDS_MAX
            } else {
                0
            })
            | (if self.switch_is_limit {
                Self::SWITCH_IS_LIMIT
            } else {
                0
            })
    }
}

impl Default for HomingSettings {
    fn default() -> Self {
        Self::NONE
    }
}

/// HOMING_SET's data and the HOMING report's: a joint and its settings.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct HomingSet {
    /// The joint, 0-7.
    pub joint: u8,
    /// Its settings.
    pub settings: HomingSettings,
}

impl HomingSet {
    /// Reads 24 bytes; `None` for a joint past 7, unknown flag bits or settings that
    /// cannot run ([`HomingSettings::is_valid`]).
    pub(crate) fn read(b: &[u8]) -> Option<HomingSet> {
        let joint = u8_at(b, 0);
        let flags = u8_at(b, 1);
        if usize::from(joint) >= crate::MAX_JOINTS || flags & !0b111 != 0 {
            return None;
        }
        let settings = HomingSettings {
            enabled: flags & HomingSettings::ENABLED != 0,
            towards_max: flags & HomingSettings::TOWARDS_MAX != 0,
            switch_is_limit: flags & HomingSettings::SWITCH_IS_LIMIT != 0,
            order: u8_at(b, 2),
            seek_rate_hz: u32_le(b, 4),
            approach_rate_hz: u32_le(b, 8),
            backoff_steps: u32_le(b, 12),
            max_travel_steps: u32_le(b, 16),
            offset: u32_le(b, 20) as i32,
        };
        settings.is_valid().then_some(HomingSet { joint, settings })
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>, at: usize) {
        let s = &self.settings;
        w.put(at, &[self.joint, s.flags(), s.order, 0]);
        w.u32(at + 4, s.seek_rate_hz);
        w.u32(at + 8, s.approach_rate_hz);
        w.u32(at + 12, s.backoff_steps);
        w.u32(at + 16, s.max_travel_steps);
        w.u32(at + 20, s.offset as u32);
    }
}

/// Where the homing cycle is (the SWITCHES report's first byte).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum HomingPhase {
    /// No HOME since boot.
    #[default]
    Never = 0,
    /// A cycle is running (`joint` is being homed).
    Homing = 1,
    /// The last cycle homed every joint set to home.
    Homed = 2,
    /// The last cycle failed (`joint` and `error` say where and why).
    Failed = 3,
}

/// Why a homing cycle failed (the SWITCHES report's `error`; each names the joint).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub enum HomingFailure {
    /// The seek travelled its maximum without the switch.
    SeekTravel = 1,
    /// The switch still read pressed at the end of the back-off.
    BackOffStillActive = 2,
    /// The slow approach travelled twice the back-off without the switch.
    ApproachMissed = 3,
    /// Stopped from outside (STOPPED, a limit switch, the e-stop input).
    Aborted = 4,
    /// The joint's settings cannot be run.
    BadSettings = 5,
}

impl HomingFailure {
    /// From its byte.
    pub const fn from_u8(b: u8) -> Option<HomingFailure> {
        Some(match b {
            1 => HomingFailure::SeekTravel,
            2 => HomingFailure::BackOffStillActive,
            3 => HomingFailure::ApproachMissed,
            4 => HomingFailure::Aborted,
            5 => HomingFailure::BadSettings,
            _ => return None,
        })
    }

    /// What it means, for people.
    pub const fn text(self) -> &'static str {
        match self {
            HomingFailure::SeekTravel => "the seek travelled its maximum without the switch",
            HomingFailure::BackOffStillActive => "the switch stayed pressed after the back-off",
            HomingFailure::ApproachMissed => "the slow approach did not find the switch again",
            HomingFailure::Aborted => "stopped (STOPPED, a limit switch or the e-stop input)",
            HomingFailure::BadSettings => "its homing settings cannot be run",
        }
    }
}

/// The SWITCHES report (0x30): the homing cycle's progress and the switch inputs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct SwitchesReport {
    /// Where the cycle is.
    pub phase: HomingPhase,
    /// The joint being homed, or the one that failed (0 otherwise).
    pub joint: u8,
    /// Why it failed (`None` unless [`HomingPhase::Failed`]).
    pub error: Option<HomingFailure>,
    /// Joints homed since boot (bit per joint).
    pub homed: u8,
    /// Home switches pressed now (bit per joint).
    pub home_active: u8,
    /// Min limit switches pressed now.
    pub min_active: u8,
    /// Max limit switches pressed now.
    pub max_active: u8,
    /// The limit the controller is latched on: the joint (bits 0-6) and the side
    /// (bit 7: max); `None` (0xFF on the wire) when not latched.
    pub latched: Option<u8>,
}

impl SwitchesReport {
    pub(crate) fn read(b: &[u8]) -> Option<SwitchesReport> {
        let phase = match u8_at(b, 0) {
            0 => HomingPhase::Never,
            1 => HomingPhase::Homing,
            2 => HomingPhase::Homed,
            3 => HomingPhase::Failed,
            _ => return None,
        };
        let error = match u8_at(b, 2) {
            0 => None,
            e => Some(HomingFailure::from_u8(e)?),
        };
        let latched = match u8_at(b, 7) {
            0xFF => None,
            l => Some(l),
        };
        Some(SwitchesReport {
            phase,
            joint: u8_at(b, 1),
            error,
            homed: u8_at(b, 3),
            home_active: u8_at(b, 4),
            min_active: u8_at(b, 5),
            max_active: u8_at(b, 6),
            latched,
        })
    }

    pub(crate) fn write(&self, w: &mut Writer<'_>, at: usize) {
        w.put(
            at,
            &[
                self.phase as u8,
                self.joint,
                self.error.map_or(0, |e| e as u8),
                self.homed,
                self.home_active,
                self.min_active,
                self.max_active,
                self.latched.unwrap_or(0xFF),
            ],
        );
    }
}
