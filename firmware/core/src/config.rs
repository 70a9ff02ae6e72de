//! Capacities, limits and board defaults of the controller.

use protocol::MAX_JOINTS;

// The per-board figures (step rates, step budget, buffer capacity, timer clocks) are in
// `crate::profile`, one checked description per board.

/// Default RETURN speed limit of every joint, steps per second: a quarter of a 1.8 degree,
/// 16-microstep motor's 5 rev/s, gentle enough for an arm returning blind.
pub const DEFAULT_RETURN_SPEED: u32 = 4_000;

/// Default RETURN acceleration limit of every joint, steps per second squared: full
/// speed in 0.5 s.
pub const DEFAULT_RETURN_ACCEL: u32 = 8_000;

/// Length of one RETURN point, microseconds: 10 ms is short enough that the trapezoid's
/// corners are followed closely and long enough that a 30 s return needs only 3000 points.
pub const DEFAULT_RETURN_SEGMENT_US: u32 = 10_000;

// The protocol's timing and memory of ownership and duplicate detection, and the largest
// host window, are declared once, in the protocol crate (hosts need them too).
// The network path of the board and of sim-host is sized for `HOST_WINDOW`
// (`bus::INBOX_QUEUE`, the board's Ethernet ring and UDP socket).
pub use protocol::limits::{DUPLICATE_MEMORY, DUPLICATE_WINDOW_US, HOST_WINDOW, OWNER_TIMEOUT_US};

/// Everything about the controller that differs between boards (and the simulator).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ControllerConfig {
    /// Highest step rate of one joint (STATUS `max_step_rate_hz`); points asking for more
    /// are refused with INVALID_POINT. Must not exceed the step engine's own limit.
    pub max_step_rate_hz: u32,
    /// Trajectory points buffered; clamped to the storage's compile-time size.
    pub capacity: usize,
    /// Input clock of the gripper timer (STATUS `pwm_timer_clock_hz`).
    pub pwm_timer_clock_hz: u32,
    /// RETURN: speed limit of each joint, steps per second (0 is treated as 1).
    pub return_speed: [u32; MAX_JOINTS],
    /// RETURN: acceleration limit of each joint, steps per second squared (0 is treated
    /// as 1).
    pub return_accel: [u32; MAX_JOINTS],
    /// RETURN: length of each generated point, microseconds.
    pub return_segment_us: u32,
    /// What a stop (STOPPED, the wired e-stop input) does to a servo PWM on the gripper
    /// timer; a counted burst is always cut (issue 30).
    pub servo_on_stop: ServoOnStop,
}

/// What a stop (STOPPED, the wired e-stop input) does to a servo PWM (PWM_START with
/// `PluseCount` 0) on the gripper timer (issue 30; docs/PROTOCOL.md, PWM_START). A counted
/// burst (a stepper gripper) is motion and every stop cuts it; a servo's PWM is a held
/// position, and cutting it makes most hobby servos go limp, so that a closed gripper
/// drops its part. Either can be right for a given arm, so it is a board setting.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ServoOnStop {
    /// The servo PWM keeps its duty through a stop (the gripper keeps holding; STATUS flag
    /// bit 6 stays set); PWM_STOP still cuts it. The default.
    #[default]
    Hold,
    /// A stop cuts the servo PWM too, as PWM_STOP does (STATUS flag bit 6 clear).
    Cut,
}

impl ServoOnStop {
    /// Whether a stop cuts a gripper output started with this `pulse_count` (PWM_START):
    /// the one rule the controller, the board's interrupts and the simulator apply.
    pub const fn cuts(self, pulse_count: i32) -> bool {
        pulse_count != 0 || matches!(self, ServoOnStop::Cut)
    }
}

impl ControllerConfig {
    /// The NUCLEO-H743ZI2 board's configuration (its profile's,
    /// [`crate::profile::NUCLEO_H743ZI2`]).
    pub const BOARD: ControllerConfig = crate::profile::NUCLEO_H743ZI2.controller_config();
}

impl Default for ControllerConfig {
    fn default() -> Self {
        Self::BOARD
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stop_cuts_every_burst_and_a_servo_only_under_cut() {
        for pulses in [1, -1, 8000, i32::MIN, i32::MAX] {
            assert!(ServoOnStop::Hold.cuts(pulses));
            assert!(ServoOnStop::Cut.cuts(pulses));
        }
        assert!(!ServoOnStop::Hold.cuts(0));
        assert!(ServoOnStop::Cut.cuts(0));
        assert_eq!(ServoOnStop::default(), ServoOnStop::Hold);
    }
}
