//! Issue 33, homing on switches in the simulator's physical model (`--position`,
//! `--home-switch`): HOME from 10 random physical positions (each reached by a jog, the
//! count then made wrong with LOCATION_SETTING, as a joint that lost steps) ends each time
//! with the reported count equal to the physical position minus the switch's plus the
//! offset, to the step; a seek past its maximum travel fails naming the joint (SWITCHES
//! report); HOME without a joint set to home is refused HOMING_FAILED; HOMING_GET reads
//! back what HOMING_SET stored. (One simulated controller per process: this file is its
//! own test binary.)

mod common;

use std::time::{Duration, Instant};

use common::{Client, OwnedReport, points_through, temp_path};
use protocol::{
    Command, HomingFailure, HomingPhase, HomingSet, HomingSettings, MAX_JOINTS, State, StatusCode,
    SwitchesReport,
};
use sim_host::options::SimOptions;

/// Joint 0 starts here, physically; its home switch (min side) is at `SWITCH`.
const START: i64 = 1_234;
const SWITCH: i64 = -200;
const OFFSET: i32 = 100;

fn settings(max_travel_steps: u32) -> HomingSettings {
    HomingSettings {
        enabled: true,
        towards_max: false,
        switch_is_limit: false,
        order: 0,
        seek_rate_hz: 4_000,
        approach_rate_hz: 2_000,
        // More than the seek runs on past the switch before its stop: the simulator's step
        // thread sees edges every few ms and the task reacts after it, 16 steps per real
        // ms at this seek rate and time scale, so a machine ten times busier still stops
        // within it.
        backoff_steps: 2_000,
        max_travel_steps,
        offset: OFFSET,
    }
}

/// HOME, then the SWITCHES report once the cycle is over (polled, bounded).
fn home(client: &mut Client) -> SwitchesReport {
    client.ok(&Command::Home);
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let report = client.switches();
        if report.phase != HomingPhase::Homing {
            assert_eq!(client.status().state, State::Stopped);
            return report;
        }
        assert!(Instant::now() < deadline, "homing never ended: {report:?}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// A jog of joint 0 by `delta` steps from count `from` (points of 10 ms at 1 step/ms at
/// most).
fn jog(client: &mut Client, from: i32, delta: i32) {
    let n = (delta.abs() / 10).max(1);
    let targets: Vec<[i32; MAX_JOINTS]> = (1..=n)
        .map(|i| [from + delta * i / n, 0, 0, 0, 0, 0, 0, 0])
        .collect();
    let status = client.run_points(
        &points_through([from, 0, 0, 0, 0, 0, 0, 0], &targets, 10_000),
        Duration::from_secs(60),
    );
    assert_eq!(status.executed as i32, n, "{status:?}");
}

#[test]
fn homing_from_random_positions_ends_at_the_switch_plus_offset_to_the_step() {
    let mut options = SimOptions::defaults();
    options.bind.set_port(0);
    options.settings = Some(temp_path("homing.txt"));
    options.joints = Some(2);
    options.time_scale = 4.0;
    options.positions = vec![(0, START)];
    options.home_switches = vec![(0, SWITCH, arm_core::switches::Side::Min)];
    let board = sim_host::app::start_in_background(&options).expect("the simulator starts");
    let mut client = Client::new(board.local_addr().expect("a UDP socket"));
    let physical = || START + board.motors.positions()[0];

    // Nothing set to home yet: refused, nothing moves.
    let ack = client.command(&Command::Home);
    assert_eq!(ack.status, StatusCode::HomingFailed);
    assert_eq!(client.switches().phase, HomingPhase::Never);

    client.ok(&Command::HomingSet(HomingSet {
        joint: 0,
        settings: settings(20_000),
    }));
    client.ok(&Command::HomingGet { joint: 0 });
    let deadline = Instant::now() + Duration::from_secs(2);
    let read = loop {
        let left = deadline
            .checked_duration_since(Instant::now())
            .expect("a HOMING report");
        if let Some((_, OwnedReport::Homing(h))) = client.receive(left) {
            break h;
        }
    };
    assert_eq!(read.settings, settings(20_000));

    // 10 random physical positions, either side of the switch (xorshift, fixed seed); on
    // the pressed side within the back-off (from deeper in, the switch still reads pressed
    // after the back-off, and the cycle fails naming the joint, by design).
    let mut state = 0x2545_f491_u32;
    let mut count = client.location().position[0];
    for run in 0..10 {
        state ^= state << 13;
        state ^= state >> 17;
        state ^= state << 5;
        let target = SWITCH + i64::from(state % 3_000) - 300;
        let delta = (target - physical()) as i32;
        if delta != 0 {
            jog(&mut client, count, delta);
        }
        assert_eq!(physical(), target);
        // The count goes wrong, as after lost steps.
        let wrong = (state % 10_000) as i32 - 5_000;
        client.ok(&Command::LocationSetting(protocol::Location {
            position: [wrong, 0, 0, 0, 0, 0, 0, 0],
            state: 0,
        }));
        let report = home(&mut client);
        assert_eq!(
            report.phase,
            HomingPhase::Homed,
            "run {run} from physical {target}: {report:?}, now at physical {}",
            physical()
        );
        assert_eq!(report.homed & 1, 1);
        count = client.location().position[0];
        let expected = physical() - SWITCH + i64::from(OFFSET);
        eprintln!(
            "run {run}: from physical {target} (count set to {wrong}): homed at physical {}, count {count}, expected {expected}",
            physical()
        );
        assert_eq!(i64::from(count), expected, "run {run}");
    }

    // A seek past its maximum travel fails naming the joint; the arm stops.
    jog(&mut client, count, 1_500);
    client.ok(&Command::HomingSet(HomingSet {
        joint: 0,
        settings: settings(500),
    }));
    let before = physical();
    let report = home(&mut client);
    assert_eq!(report.phase, HomingPhase::Failed);
    assert_eq!(report.joint, 0);
    assert_eq!(report.error, Some(HomingFailure::SeekTravel));
    assert_eq!(physical(), before - 500, "the seek travelled its maximum");
    board.shut_down();
}
