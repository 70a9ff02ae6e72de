//! Issue 33, hard limits in the simulator's physical model (`--limit-switch`): a trajectory
//! that runs joint 0 into its max limit switch stops every joint at the step edge that
//! closed it (the VCD trace: no STEP edge on any joint later than one step period after
//! it; the motors stand exactly where the switch closed); the controller latches: RUNING
//! refused LIMIT_LATCHED, STOP_CAUSE names the joint and the side; after UNLOCK points
//! further in are refused and jogging away works. (One simulated controller per process:
//! this file is its own test binary.)

mod common;

use std::time::{Duration, Instant};

use armctl::vcd;
use common::{Client, OwnedReport, points_through, temp_path};
use protocol::{Command, MAX_JOINTS, State, StatusAsk, StatusCode, StopCause, StopReport};
use sim_host::options::SimOptions;

/// Joint 0's step period on the way in: 10 steps per 50 ms point, 200 steps/s.
const STEP_PERIOD_NS: u64 = 5_000_000;
/// Where joint 0 physically starts, and its max limit switch.
const START: i64 = 100;
const MAX_LIMIT: i64 = 300;

fn stop_report(client: &mut Client) -> StopReport {
    client.ok(&Command::StatusWith(StatusAsk {
        look_only: true,
        stop_cause: true,
        ..StatusAsk::default()
    }));
    let deadline = Instant::now() + Duration::from_secs(2);
    while let Some(left) = deadline.checked_duration_since(Instant::now()) {
        if let Some((_, OwnedReport::StopCause(stop))) = client.receive(left) {
            return stop;
        }
    }
    panic!("no STOP_CAUSE report");
}

fn upload(client: &mut Client, points: &[protocol::Point]) -> StatusCode {
    client.ok(&Command::New {
        count: points.len() as u16,
    });
    for chunk in points.chunks(12) {
        let ack = client.command(&Command::Pending(protocol::PointList::Points(chunk)));
        if ack.status != StatusCode::Ok {
            return ack.status;
        }
    }
    StatusCode::Ok
}

#[test]
fn a_max_limit_stops_every_joint_at_its_edge_latches_and_unlocks_away_only() {
    let trace = temp_path("limit-switch.vcd");
    let mut options = SimOptions::defaults();
    options.bind.set_port(0);
    options.trace = Some(trace.clone());
    options.settings = Some(temp_path("limit-switch.txt"));
    options.joints = Some(2);
    options.positions = vec![(0, START)];
    options.limit_switches = vec![(0, -1_000, MAX_LIMIT)];
    let board = sim_host::app::start_in_background(&options).expect("the simulator starts");
    let mut client = Client::new(board.local_addr().expect("a UDP socket"));
    assert_eq!(client.status().state, State::Stopped);

    // 100 points of 50 ms: joint 0 +10 steps each (to count 1000), joint 1 +15 each.
    let targets: Vec<[i32; MAX_JOINTS]> = (1..=100)
        .map(|i| [i * 10, i * 15, 0, 0, 0, 0, 0, 0])
        .collect();
    let points = points_through([0; MAX_JOINTS], &targets, 50_000);
    assert_eq!(upload(&mut client, &points), StatusCode::Ok);
    client.ok(&Command::Runing);
    let status = client.wait_stopped(Duration::from_secs(20));
    assert_eq!(status.state, State::Stopped);
    assert!(status.executed < 100, "the run was cut: {status:?}");

    // The motors stand where the switch closed, to the step.
    let motors = board.motors.positions();
    assert_eq!(
        START + motors[0],
        MAX_LIMIT,
        "joint 0 stopped on its switch"
    );
    let stop = stop_report(&mut client);
    assert_eq!(stop.cause, Some(StopCause::LimitSwitch));
    assert_eq!(stop.detail, 0x80, "joint 0, max side");

    // Latched: RUNING refused with the limit's status, however often (the points, away
    // from the switch, are taken: they may run after UNLOCK).
    let here = [motors[0] as i32, motors[1] as i32, 0, 0, 0, 0, 0, 0];
    let away: Vec<[i32; MAX_JOINTS]> = (1..=10)
        .map(|i| [here[0] - 5 * i, here[1], 0, 0, 0, 0, 0, 0])
        .collect();
    assert_eq!(
        upload(&mut client, &points_through(here, &away, 50_000)),
        StatusCode::Ok
    );
    for _ in 0..3 {
        let ack = client.command(&Command::Runing);
        assert_eq!(ack.status, StatusCode::LimitLatched);
    }
    client.ok(&Command::Stopped);

    // Unlocked, the switch still pressed: further in is refused, away runs.
    client.ok(&Command::Unlock);
    let further: Vec<[i32; MAX_JOINTS]> = (1..=5)
        .map(|i| [here[0] + i, here[1], 0, 0, 0, 0, 0, 0])
        .collect();
    assert_eq!(
        upload(&mut client, &points_through(here, &further, 50_000)),
        StatusCode::LimitLatched
    );
    client.ok(&Command::Stopped);
    let status = client.run_points(
        &points_through(here, &away, 50_000),
        Duration::from_secs(10),
    );
    assert_eq!(status.executed, 10);
    assert_eq!(board.motors.positions()[0], motors[0] - 50);

    board.shut_down();
    // The trace: the rise that closed the switch is joint 0's (MAX_LIMIT - START)th; no
    // STEP edge on any joint after it by more than a step period.
    let vcd = vcd::read_changes(&trace).unwrap();
    let rises = |name: &str| -> Vec<u64> {
        vcd.changes
            .get(name)
            .map(|c| {
                c.iter()
                    .filter(|(_, v)| v == "1")
                    .map(|(t, _)| *t)
                    .collect()
            })
            .unwrap_or_default()
    };
    let step0 = rises("step0");
    let closed = step0[(MAX_LIMIT - START) as usize - 1];
    let resumed = step0[(MAX_LIMIT - START) as usize];
    let last = (0..2)
        .flat_map(|j| rises(&format!("step{j}")))
        .filter(|&t| t < resumed)
        .max()
        .unwrap();
    eprintln!(
        "limit closed at {closed} ns; last STEP edge of any joint before the unlocked jog {last} ns ({} ns after; step period {STEP_PERIOD_NS} ns)",
        last - closed
    );
    assert!(last <= closed + STEP_PERIOD_NS);
}
