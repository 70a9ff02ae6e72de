//! Issue 30 part 1 in the simulator, the default `--servo-on-stop hold`: every stop (a
//! STOPPED from another host, the wired e-stop input) cuts a gripper burst within 100 ms,
//! STATUS bit 6 clear; a servo PWM keeps its duty, bit 6 set, until PWM_STOP
//! (`gripper_trials`). One simulated controller per process: its own test binary.

mod common;
mod gripper_trials;

#[test]
fn every_stop_cuts_a_gripper_burst_and_a_servo_holds() {
    gripper_trials::run("gripper-stop-hold", |_| {}, false);
}
