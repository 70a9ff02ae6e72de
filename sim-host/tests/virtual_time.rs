//! The simulated controller on virtual time (issue 19): sim-host's own hardware models and
//! the firmware's tasks, driven in this thread by `VirtualBoard`, whose clock moves only
//! when the test moves it. No sleep, no socket, no deadline in wall-clock time: a loaded
//! machine makes these tests slower, never different. The same checks as the process
//! tests in `controller.rs` where those depend on the controller's timing (pulse times,
//! a stop mid-run, a gripper burst's length).

mod virtual_host;

use armctl::vcd;
use protocol::{Command, MAX_JOINTS, Pwm, State, StatusFlags};
use virtual_host::*;

#[test]
fn status_on_virtual_time() {
    let (mut board, _) = board("status", 1_000_000);
    let mut host = Host::new();
    let status = host.status(&mut board);
    assert_eq!(status.state, State::Stopped);
    assert_eq!(status.version, protocol::VERSION);
    // Nothing took any wall-clock time to happen: the clock moved only in rounds.
    assert!(
        board.clock.now_ns() < SECOND_NS / 10,
        "{} ns",
        board.clock.now_ns()
    );
}

#[test]
fn trace_pulses_match_the_commanded_steps_on_virtual_time() {
    let (mut board, trace) = board("motion", 1_000_000);
    let mut host = Host::new();
    let start = [0; MAX_JOINTS];
    let targets = [
        [100, -37, 0, 5, 1, 250, 0, 0],
        [160, -37, 0, -5, 1, 100, 0, 0],
        [150, 63, 0, 0, 2, 100, 0, 0],
    ];
    let points = points_through(start, &targets, 20_000);
    host.upload_and_run(&mut board, &points);
    let end = run_until_stopped(&mut board, SECOND_NS);
    assert_eq!(end.position, targets[2]);
    let status = host.status(&mut board);
    assert_eq!(status.executed, 3);
    assert!(!status.flags.has(StatusFlags::UNDERRUN));
    board.finish_trace();

    let vcd = vcd::read_changes(&trace).unwrap();
    let mut expected = [0u64; MAX_JOINTS];
    let mut previous = start;
    for target in targets {
        for j in 0..MAX_JOINTS {
            expected[j] += (target[j] - previous[j]).unsigned_abs() as u64;
        }
        previous = target;
    }
    for j in 0..MAX_JOINTS {
        assert_eq!(
            vcd.rising_edges(&format!("step{j}")).len() as u64,
            expected[j],
            "joint {j}"
        );
        assert_eq!(vcd.joint_position(j), i64::from(targets[2][j]), "joint {j}");
    }
    // Joint 0: 100 pulses in 20 ms, pulse i at S + (i - 1) * 200 us; then 60 in 20 ms.
    let edges = vcd.rising_edges("step0");
    let first = edges[0];
    for (i, edge) in edges.iter().take(100).enumerate() {
        assert_eq!(edge - first, i as u64 * 200_000, "pulse {}", i + 1);
    }
    let start_ns = first - 200_000;
    for (i, edge) in edges[100..160].iter().enumerate() {
        let i = i as u64 + 1;
        assert_eq!(
            edge - start_ns,
            20_000_000 + i * 20_000_000 / 60 / 1000 * 1000,
            "pulse {i}"
        );
    }
}

#[test]
fn stopped_mid_run_leaves_no_step_after_it_on_virtual_time() {
    let (mut board, trace) = board("stop", 1_000_000);
    let mut host = Host::new();
    // 10 s of joint 0 at 1000 steps/s.
    let targets: Vec<[i32; MAX_JOINTS]> =
        (1..=100).map(|i| [i * 100, 0, 0, 0, 0, 0, 0, 0]).collect();
    let points = points_through([0; MAX_JOINTS], &targets, 100_000);
    host.upload_and_run(&mut board, &points);
    // 250 ms of simulated time into the run, exactly.
    board.run_for(250_000_000);
    let before = board.motors.positions()[0];
    assert!(
        (240..=260).contains(&before),
        "{before} steps after 250 ms at 1 kHz"
    );
    let ack = host.ok(&mut board, &Command::Stopped);
    assert_eq!(ack.state, State::Stopped);
    let acked_ns = board.clock.now_ns();
    let stopped_at = board.motors.positions()[0];
    // A whole simulated second later: not one step more.
    board.run_for(SECOND_NS);
    assert_eq!(board.motors.positions()[0], stopped_at);
    let status = host.status(&mut board);
    assert!(status.flags.has(StatusFlags::STOPPED_BY_HOST));
    board.finish_trace();
    let vcd = vcd::read_changes(&trace).unwrap();
    assert_eq!(vcd.joint_position(0), stopped_at);
    // The last rise of STEP came before the ACK of STOPPED (one round, 10 us, at most
    // after the datagram was delivered), and the line is low. A pulse high at the stop
    // keeps its width (PROTOCOL.md, STOPPED: a stop never cuts a pulse short): the only
    // change after the ACK is such a fall, as wide after its rise as the run's first.
    let rises = vcd.rising_edges("step0");
    let last_rise = *rises.last().unwrap();
    assert!(
        last_rise <= acked_ns,
        "STEP rose at {last_rise} ns, after the ACK at {acked_ns}"
    );
    let changes = &vcd.changes["step0"];
    let width = |rise: u64| {
        changes
            .iter()
            .find(|(t, v)| *t > rise && v == "0")
            .map(|(t, _)| t - rise)
            .expect("every pulse falls")
    };
    assert_eq!(width(last_rise), width(rises[0]), "the last pulse was cut");
    let after: Vec<_> = changes.iter().filter(|(t, _)| *t > acked_ns).collect();
    assert!(after.len() <= 1, "STEP changed after the ACK: {after:?}");
    let (_, last_v) = changes.last().unwrap();
    assert_eq!(last_v, "0", "STEP left high");
    println!(
        "STOPPED at {acked_ns} ns: last rise {last_rise} ns, pulse width {} ns, {} change after the ACK",
        width(last_rise),
        after.len()
    );
}

#[test]
fn a_gripper_burst_lasts_exactly_its_pulses_on_virtual_time() {
    let (mut board, trace) = board("gripper", 200_000_000);
    let mut host = Host::new();
    // 200 MHz / (200 * 1000) = 1 kHz; 20 pulses = 20 ms.
    host.ok(
        &mut board,
        &Command::PwmStart(Pwm {
            psc: 199,
            arr: 999,
            ccr1: 500,
            pulse_count: 20,
        }),
    );
    assert!(
        host.status(&mut board).flags.has(StatusFlags::PWM_ACTIVE),
        "on right after"
    );
    board.run_for(30_000_000);
    assert!(
        !host.status(&mut board).flags.has(StatusFlags::PWM_ACTIVE),
        "off 30 ms later"
    );
    board.finish_trace();
    let vcd = vcd::read_changes(&trace).unwrap();
    let (on, off) = vcd.high_span("gripper_pwm_active").expect("on, then off");
    assert_eq!(off - on, 20_000_000, "20 periods of 1 ms");
}

/// STATUS `executed` counts a point once its periods are all written to the step
/// hardware, which may be [`BoardProfile::step_dma_lead_ns`] ahead of the pins: a host
/// that takes `executed > 0` for "moving" is early. tests/tests/estop_input.rs did (CI,
/// 2026-11-29: its e-stop input opened 314 ms in, after STATUS said RUNNING with points
/// executed, before the run's first pulse). What it waits for now, `executed` past the
/// lead's worth of points, is checked here against the pins, poll by poll.
///
/// [`BoardProfile::step_dma_lead_ns`]: arm_core::profile::BoardProfile::step_dma_lead_ns
#[test]
fn executed_runs_ahead_of_the_pins_by_at_most_the_dma_lead_on_virtual_time() {
    const SEGMENT_NS: u64 = 10_000_000;
    let (mut board, trace) = board("executed-lead", sim_host::app::PROFILE.step_timer_hz);
    let mut host = Host::new();
    // The system test's run: 10 ms points of 2 steps on joint 0 (200 steps/s).
    let targets: Vec<[i32; MAX_JOINTS]> = (1..=30)
        .map(|k| core::array::from_fn(|j| if j == 0 { 2 * k } else { 0 }))
        .collect();
    let points = points_through([0; MAX_JOINTS], &targets, (SEGMENT_NS / 1_000) as i32);
    host.upload_and_run(&mut board, &points);
    // (executed, the time its report had come by), every simulated millisecond: the pins
    // by then had made at least the pulses they had when STATUS counted.
    let mut polls = Vec::new();
    loop {
        let status = host.status(&mut board);
        let by = board.clock.now_ns();
        polls.push((status.executed, by));
        if status.state == State::Stopped {
            break;
        }
        assert!(by < SECOND_NS, "the run did not end");
        board.run_for(1_000_000);
    }
    board.finish_trace();
    let edges = vcd::read_changes(&trace).unwrap().rising_edges("step0");
    assert_eq!(edges.len(), 60);
    let pulses_by = |t: u64| edges.iter().filter(|e| **e <= t).count();

    let lead = sim_host::app::PROFILE.step_dma_lead_ns();
    let moving_after = sim_host::app::PROFILE.executed_once_pulsed(SEGMENT_NS) as u16;
    let early = polls
        .iter()
        .filter(|(executed, by)| *executed > 0 && pulses_by(*by) == 0)
        .count();
    assert!(
        early > 0,
        "no STATUS showed a point executed before a pulse"
    );
    for (executed, by) in &polls {
        // Point k's last pulse is at most `lead` after STATUS counts it.
        let points_by_pins = pulses_by(by + lead) / 2;
        assert!(
            usize::from(*executed) <= points_by_pins,
            "at {by} ns: {executed} executed, pins through point {points_by_pins}"
        );
        if *executed >= moving_after {
            assert!(pulses_by(*by) > 0, "at {by} ns: {executed} executed");
        }
    }
    eprintln!(
        "{early} STATUS polls showed points executed before the first pulse; lead {lead} ns, moving once {moving_after} are executed"
    );
}
