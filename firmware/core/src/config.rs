//! Capacities, limits and board defaults of the controller.

use protocol::MAX_JOINTS;

/// Trajectory points the H743 board buffers: 8192 * 36 bytes = 288 KiB of its 512 KiB
/// AXI SRAM, i.e. 80 s of 10 ms points, so a host streaming over a congested link has
/// seconds of slack before an underrun.
pub const BOARD_TRAJECTORY_CAPACITY: usize = 8192;

/// Highest step rate of one joint on the board: 100 kHz (10 us between pulses) leaves room
/// for the drivers' pulse width and DIR setup time, and is what common stepper drivers
/// accept.
pub const BOARD_MAX_STEP_RATE_HZ: u32 = 100_000;

/// Steps per second of all joints together on the board: 8 joints x 500 kHz, about a
/// third of the 400 MHz Cortex-M7 at the measured 29 instructions per step
/// (scripts/step-cost; derivation in docs/PROTOCOL.md, "Step rate budget"). STATUS
/// `step_budget_hz`; [`crate::Controller::set_step_budget_hz`] changes it.
pub const BOARD_STEP_BUDGET_HZ: u32 = 4_000_000;

/// Default RETURN speed limit of every joint, steps per second: a quarter of a 1.8 degree,
/// 16-microstep motor's 5 rev/s, gentle enough for an arm returning blind.
pub const DEFAULT_RETURN_SPEED: u32 = 4_000;

/// Default RETURN acceleration limit of every joint, steps per second squared: full
/// speed in 0.5 s.
pub const DEFAULT_RETURN_ACCEL: u32 = 8_000;

/// Length of one RETURN point, microseconds: 10 ms is short enough that the trapezoid's
/// corners are followed closely and long enough that a 30 s return needs only 3000 points.
pub const DEFAULT_RETURN_SEGMENT_US: u32 = 10_000;

/// Gripper timer input clock of the H743 board: the firmware runs the CPU at 400 MHz and
/// the APB timer clocks at 200 MHz, so TIM15 (the gripper) counts at 200 MHz (the board
/// passes its measured clock at boot anyway). The simulator's gripper uses this figure, so
/// that a host computes the same PSC/ARR for both.
pub const BOARD_PWM_TIMER_CLOCK_HZ: u32 = 200_000_000;

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
}

impl ControllerConfig {
    /// The NUCLEO-H743ZI2 board's configuration.
    pub const BOARD: ControllerConfig = ControllerConfig {
        return_speed: [DEFAULT_RETURN_SPEED; MAX_JOINTS],
        return_accel: [DEFAULT_RETURN_ACCEL; MAX_JOINTS],
        return_segment_us: DEFAULT_RETURN_SEGMENT_US,
        max_step_rate_hz: BOARD_MAX_STEP_RATE_HZ,
        capacity: BOARD_TRAJECTORY_CAPACITY,
        pwm_timer_clock_hz: BOARD_PWM_TIMER_CLOCK_HZ,
    };
}

impl Default for ControllerConfig {
    fn default() -> Self {
        Self::BOARD
    }
}
