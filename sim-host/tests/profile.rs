//! The simulator is the NUCLEO-H743ZI2 by default (issue 19, "One board profile"): it
//! accepts what the board accepts and refuses what the board refuses.

mod common;

use std::time::Duration;

use common::{Sim, points_through, temp_path};
use protocol::{Command, MAX_JOINTS, StatusCode, StatusFlags};

/// The NUCLEO's per-joint step rate limit (its STATUS `max_step_rate_hz`: 200 kHz).
const NUCLEO_MAX_STEP_RATE_HZ: u32 = arm_core::profile::NUCLEO_H743ZI2.max_step_rate_hz();

/// Length of the test's points, microseconds.
const POINT_US: i32 = 10_000;

/// Steps of joint 0 in one `POINT_US` point at `rate_hz`.
fn steps_at(rate_hz: u32) -> i32 {
    (u64::from(rate_hz) * POINT_US as u64 / 1_000_000) as i32
}

/// A trajectory at the NUCLEO's per-joint limit, and one at 150 kHz, are accepted and run
/// to the last step; one a step above the limit is refused INVALID_POINT.
#[test]
fn the_nucleos_per_joint_limit_is_the_simulators() {
    let sim = Sim::start(&["--settings", temp_path("limit.txt").to_str().unwrap()]);
    let mut client = sim.client();
    let mut position = 0;
    for rate in [150_000, NUCLEO_MAX_STEP_RATE_HZ] {
        let mut target = [0; MAX_JOINTS];
        target[0] = position + steps_at(rate);
        let mut start = [0; MAX_JOINTS];
        start[0] = position;
        let points = points_through(start, &[target], POINT_US);
        let status = client.run_points(&points, Duration::from_secs(10));
        assert_eq!(status.executed, 1, "{rate} Hz: {status:?}");
        assert!(
            !StatusFlags(status.flags.0).has(StatusFlags::UNDERRUN),
            "{rate} Hz: {status:?}"
        );
        position = target[0];
        assert_eq!(client.location().position[0], position, "{rate} Hz");
    }

    let mut start = [0; MAX_JOINTS];
    start[0] = position;
    let mut target = start;
    target[0] += steps_at(NUCLEO_MAX_STEP_RATE_HZ) + 1;
    let points = points_through(start, &[target], POINT_US);
    client.ok(&Command::New { count: 1 });
    let ack = client.command(&Command::Pending(protocol::PointList::Points(&points)));
    assert_eq!(ack.status, StatusCode::InvalidPoint, "{ack:?}");
}
