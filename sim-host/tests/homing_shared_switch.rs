//! Issue 33, homing on a switch that is also the joint's limit (HOMING_SET
//! `switch_is_limit`, the board's recommended wiring: one switch per joint end, docs/BOARD.md):
//! in the simulator the home switch and the min limit switch close at the same step. The
//! limit's trip must not stop the homing cycle it is masked for (the cycle ends homed, to
//! the step, not latched); at any other time the same switch is a hard limit (a run into
//! it stops and latches). (One simulated controller per process.)

mod common;

use std::time::{Duration, Instant};

use common::{Client, points_through, temp_path};
use protocol::{Command, HomingPhase, HomingSet, HomingSettings, MAX_JOINTS, State, StatusCode};
use sim_host::options::SimOptions;

const START: i64 = 700;
const SWITCH: i64 = -100;
const OFFSET: i32 = 5;

#[test]
fn a_home_switch_that_is_the_limit_homes_and_still_guards_the_end() {
    let mut options = SimOptions::defaults();
    options.bind.set_port(0);
    options.settings = Some(temp_path("homing-shared.txt"));
    options.joints = Some(1);
    options.time_scale = 4.0;
    options.positions = vec![(0, START)];
    options.home_switches = vec![(0, SWITCH, arm_core::switches::Side::Min)];
    options.limit_switches = vec![(0, SWITCH, 100_000)];
    let board = sim_host::app::start_in_background(&options).expect("the simulator starts");
    let mut client = Client::new(board.local_addr().expect("a UDP socket"));
    let physical = || START + board.motors.positions()[0];

    client.ok(&Command::HomingSet(HomingSet {
        joint: 0,
        settings: HomingSettings {
            enabled: true,
            towards_max: false,
            switch_is_limit: true,
            order: 0,
            seek_rate_hz: 4_000,
            approach_rate_hz: 2_000,
            backoff_steps: 2_000,
            max_travel_steps: 5_000,
            offset: OFFSET,
        },
    }));
    client.ok(&Command::Home);
    let deadline = Instant::now() + Duration::from_secs(30);
    let report = loop {
        let report = client.switches();
        if report.phase != HomingPhase::Homing {
            break report;
        }
        assert!(Instant::now() < deadline, "homing never ended: {report:?}");
        std::thread::sleep(Duration::from_millis(20));
    };
    assert_eq!(report.phase, HomingPhase::Homed, "{report:?}");
    assert_eq!(report.latched, None, "the masked limit did not latch");
    assert_eq!(client.status().state, State::Stopped);
    let count = client.location().position[0];
    assert_eq!(i64::from(count), physical() - SWITCH + i64::from(OFFSET));

    // The joint rests on the switch (the approach stopped just past it): further in is
    // refused, away is taken.
    let further = points_through(
        [count, 0, 0, 0, 0, 0, 0, 0],
        &[[count - 5, 0, 0, 0, 0, 0, 0, 0]],
        10_000,
    );
    client.ok(&Command::New { count: 1 });
    let ack = client.command(&Command::Pending(protocol::PointList::Points(&further)));
    assert_eq!(
        ack.status,
        StatusCode::LimitLatched,
        "further into the switch"
    );
    client.ok(&Command::Stopped);
    let away: Vec<[i32; MAX_JOINTS]> = (1..=30)
        .map(|i| [count + 10 * i, 0, 0, 0, 0, 0, 0, 0])
        .collect();
    client.run_points(
        &points_through([count, 0, 0, 0, 0, 0, 0, 0], &away, 10_000),
        Duration::from_secs(30),
    );
    let count = count + 300;
    // After homing the switch is a hard limit again: a run into it stops and latches.
    let targets: Vec<[i32; MAX_JOINTS]> = (1..=50)
        .map(|i| [count - 10 * i, 0, 0, 0, 0, 0, 0, 0])
        .collect();
    let points = points_through([count, 0, 0, 0, 0, 0, 0, 0], &targets, 10_000);
    let status = client.run_points(&points, Duration::from_secs(30));
    assert!(status.executed < 50, "{status:?}");
    assert_eq!(physical(), SWITCH, "stopped on the switch");
    assert_eq!(client.switches().latched, Some(0));
    assert_eq!(
        client.command(&Command::Runing).status,
        StatusCode::LimitLatched
    );
}
