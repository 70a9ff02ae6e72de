//! Issue 30 part 1 in the simulator with `--servo-on-stop cut`: every stop (a STOPPED from
//! another host, the wired e-stop input) cuts a gripper burst and a servo PWM alike within
//! 100 ms, STATUS bit 6 clear (`gripper_trials`). One simulated controller per process:
//! its own test binary.

mod common;
mod gripper_trials;

use sim_host::options::ServoOnStopOption;

#[test]
fn every_stop_cuts_a_gripper_burst_and_a_servo() {
    gripper_trials::run(
        "gripper-stop-cut",
        |options| options.servo_on_stop = ServoOnStopOption::Cut,
        true,
    );
}
