//! The [`Plant`] trait: the effects the sans-io [`crate::Controller`] has on the hardware
//! while it handles a command (the trajectory task implements it over the shared step
//! engine and the devices; tests over `test_support::FakePlant`).

use arm_step::Segment;
use protocol::{MAX_JOINTS, Pwm, UartInit};

use crate::hw::SerialError;

/// What the controller drives and queries synchronously while it handles a command.
///
/// The firmware's implementation talks to the step engine shared with the step timer
/// interrupt, the output pins, the gripper timer and the serial task's queue; tests use a
/// fake that records every call.
pub trait Plant {
    /// Joint positions in steps, counted per pulse emitted.
    fn positions(&self) -> [i32; MAX_JOINTS];
    /// Overwrites the position counters (only called while no segment runs); `false` if
    /// refused.
    fn set_positions(&mut self, positions: [i32; MAX_JOINTS]) -> bool;
    /// Emergency stop: no further step pulse, every segment handed over is dropped.
    fn stop(&mut self);
    /// Hands over the next segment of the trajectory; `false` when there is no room now
    /// (offered again later).
    fn push_segment(&mut self, segment: Segment) -> bool;
    /// Starts executing the segments handed over (and those that follow) as soon as the
    /// first one is in the engine.
    fn start(&mut self);
    /// Drives user pin 0 or 1.
    fn set_user_pin(&mut self, pin: u8, high: bool);
    /// Sets the ENABLE lines: bit j = joint j holding, bit 8 = gripper.
    fn set_enabled(&mut self, enabled: u16);
    /// Starts the gripper PWM (values already validated).
    fn gripper_start(&mut self, pwm: &Pwm);
    /// Gripper output off at once.
    fn gripper_stop(&mut self);
    /// Whether the gripper output runs (a counted burst ends by itself).
    fn gripper_active(&self) -> bool;
    /// Opens (or reopens) the pass-through serial port.
    fn serial_open(&mut self, init: &UartInit) -> Result<(), SerialError>;
    /// Closes it; whatever was not yet written is dropped.
    fn serial_close(&mut self);
    /// Queues bytes for the serial port; `false` when the queue has no room.
    fn serial_send(&mut self, bytes: &[u8]) -> bool;
    /// Changes the rate of the run under way (issue 32: HOLD, RESUME, OVERRIDE): ramps to
    /// `rate` (`arm_step::RATE_ONE` = 100 %) with the slope that adds at most `accel`
    /// steps/s^2 to a joint at `speed` steps/s, from now (or the first tick after what the
    /// step side has committed). `false`: not taken (a step backend without a warp).
    fn change_rate(&mut self, _rate: u64, _accel: u32, _speed: u32) -> bool {
        false
    }
    /// The rate the next [`Plant::start`] starts the run at (`RATE_ONE`: 100 %).
    fn set_start_rate(&mut self, _rate: u64) {}
    /// The rate now (`RATE_ONE` = 100 %) and whether it is changing; `None`: no run, or a
    /// step backend without a warp.
    fn rate_now(&self) -> Option<(u64, bool)> {
        None
    }
    /// Steps per second of all joints together the step side can place under a warp
    /// (`BoardProfile::warp_budget_hz`); 0: no limit (the default).
    fn warp_budget_hz(&self) -> u32 {
        0
    }
    /// The limit switch whose trips must not halt the steps now (issue 33: the one the
    /// homing cycle homes on, when it is also the limit; `None`: every limit halts). Set
    /// before the move that may reach it starts. Default: no switches, nothing to do.
    fn set_limit_mask(&mut self, mask: Option<(u8, crate::switches::Side)>) {
        let _ = mask;
    }
}
