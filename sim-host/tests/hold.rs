//! Issue 32's Done-when in the simulator, on virtual time (the board's producer and the
//! firmware's tasks, `VirtualBoard`; every figure is simulated time, so a slow or busy
//! machine changes none of them). Joint 0 cruises at 4,000 steps/s with ACCEL_SET 20,000
//! steps/s^2 (the trajectory ramps up and down within it):
//!
//! - HOLD 2 s into the run: the STEP train slows to a standstill within v/a (0.2 s) plus
//!   the lookahead plus 20 ms, about v^2/2a (400) steps after the ramp starts, no two
//!   consecutive intervals implying more than 1.1 x the limit, no edge for the next
//!   second; RESUME: the run completes, every point executed, the joint exactly on its
//!   last point.
//! - OVERRIDE 50 before the run (`run --speed 50`): twice the nominal time (within 2 %),
//!   ending exact; OVERRIDE 25 mid-run: the remaining time four times as long (from
//!   where it took effect), ending exact.
//! - STOPPED during a hold's ramp and at rest: no STEP edge after it was read.
//!
//! The figures are printed (`--nocapture`).

mod virtual_host;

use armctl::vcd;
use protocol::{Command, MAX_JOINTS, Point, State};
use sim_host::virtual_board::VirtualBoard;
use virtual_host::*;

/// The board's step timer: 200 MHz, so that tick rounding (5 ns) does not show in the
/// acceleration two intervals imply (VCD times are in ns).
const TICK_HZ: u32 = 200_000_000;
/// Joint 0's cruise, steps per 10 ms point: 4,000 steps/s.
const CRUISE: i32 = 40;
/// ACCEL_SET for joint 0, steps/s^2.
const ACCEL: u32 = 20_000;
/// The cruise's step interval, ns.
const INTERVAL_NS: u64 = 250_000;
/// The simulator's lookahead (its profile's `lookahead_us`), s.
const LOOKAHEAD_S: f64 = 0.1;

/// Joint 0 from rest up to `CRUISE` steps per 10 ms (+1 a point: 10,000 steps/s^2), then
/// `cruise` points at it, then down to rest; with the target after each point.
fn trajectory(cruise: usize) -> (Vec<Point>, [i32; MAX_JOINTS]) {
    let steps: Vec<i32> = (1..=CRUISE)
        .chain(std::iter::repeat_n(CRUISE, cruise))
        .chain((1..CRUISE).rev())
        .collect();
    let mut at = [0; MAX_JOINTS];
    let points = steps
        .iter()
        .map(|&s| {
            let before = at;
            at[0] += s;
            Point::from_motion(10_000, &before, &at)
        })
        .collect();
    (points, at)
}

fn accel_set(host: &mut Host, board: &mut VirtualBoard, max: u32) {
    host.ok(
        board,
        &Command::AccelSet {
            joint: 0,
            max_accel_steps_s2: max,
        },
    );
}

/// Steps/s^2 two consecutive intervals imply, the highest over rises in `from..to` (ns).
fn max_implied_accel(rises: &[u64], from: u64, to: u64) -> f64 {
    let window: Vec<u64> = rises
        .iter()
        .copied()
        .filter(|t| (from..to).contains(t))
        .collect();
    window
        .windows(3)
        .map(|w| {
            let i1 = (w[1] - w[0]) as f64 * 1e-9;
            let i2 = (w[2] - w[1]) as f64 * 1e-9;
            (1.0 / i2 - 1.0 / i1).abs() / ((i1 + i2) / 2.0)
        })
        .fold(0.0, f64::max)
}

/// The first rise at or after `from` whose interval is longer than the cruise's: where a
/// slow-down took effect.
fn slowing_from(rises: &[u64], from: u64) -> Option<usize> {
    rises
        .windows(2)
        .position(|w| w[0] >= from && w[1] - w[0] > INTERVAL_NS + 100)
}

/// Runs to the end; checks every point executed and joint 0 exactly on the last.
fn finish(host: &mut Host, board: &mut VirtualBoard, points: usize, end: [i32; MAX_JOINTS]) {
    let last = run_until_stopped(board, 60 * SECOND_NS);
    assert_eq!(last.position, end, "every joint on its last point");
    let status = host.status(board);
    assert_eq!(status.state, State::Stopped);
    assert_eq!(usize::from(status.executed), points, "every point executed");
}

#[test]
fn hold_slows_within_the_acceleration_and_resume_ends_on_the_points() {
    let (mut board, trace) = board("hold", TICK_HZ);
    let mut host = Host::new();
    accel_set(&mut host, &mut board, ACCEL);
    let (points, end) = trajectory(400);
    host.upload_and_run(&mut board, &points);
    board.run_for(2 * SECOND_NS);
    let hold_ns = board.clock.now_ns();
    host.ok(&mut board, &Command::Hold);
    board.run_for(3 * SECOND_NS / 2);
    let resume_ns = board.clock.now_ns();
    host.ok(&mut board, &Command::Resume);
    finish(&mut host, &mut board, points.len(), end);
    board.finish_trace();

    let vcd = vcd::read_changes(&trace).unwrap();
    assert_eq!(vcd.joint_position(0), i64::from(end[0]));
    let rises = vcd.rising_edges("step0");
    let held: Vec<u64> = rises
        .iter()
        .copied()
        .filter(|t| (hold_ns..resume_ns).contains(t))
        .collect();
    let last = *held.last().expect("steps after the hold");
    let next = rises
        .iter()
        .copied()
        .find(|&t| t > last)
        .expect("the resume's steps");
    let to_rest = (last - hold_ns) as f64 * 1e-9;
    let ramp = slowing_from(&rises, hold_ns).expect("a slow-down");
    let ramp_ns = rises[ramp];
    let ramp_steps = rises[ramp + 1..].iter().filter(|&&t| t <= last).count();
    let ratio = max_implied_accel(&rises, hold_ns.saturating_sub(SECOND_NS / 10), resume_ns)
        / f64::from(ACCEL);
    let quiet = (next - last) as f64 * 1e-9;
    println!(
        "hold 2 s into the run: last step {to_rest:.4} s after HOLD was sent (bound v/a + \
         lookahead + 20 ms = {:.3} s); the ramp began {:.4} s after it; {} steps after HOLD, \
         {ramp_steps} from the ramp's start (v^2/2a = 400); max implied acceleration / \
         limit {ratio:.4}; no edge for {quiet:.3} s until the resume",
        0.2 + LOOKAHEAD_S + 0.02,
        (ramp_ns - hold_ns) as f64 * 1e-9,
        held.len(),
    );
    assert!(to_rest <= 0.2 + LOOKAHEAD_S + 0.02, "{to_rest} s to rest");
    assert!((395..=405).contains(&ramp_steps), "{ramp_steps} steps");
    assert!(ratio <= 1.1, "{ratio} x the limit");
    assert!(quiet >= 1.0, "an edge {quiet} s after the last");
    assert!(next >= resume_ns, "no edge before the resume");
}

/// The span from the first to the last rise of joint 0, ns, and the rises.
fn run_span(name: &str, speed: Option<u8>) -> (u64, Vec<u64>) {
    let (mut board, trace) = board(name, TICK_HZ);
    let mut host = Host::new();
    if let Some(percent) = speed {
        host.ok(&mut board, &Command::Override { percent });
    }
    let (points, end) = trajectory(60);
    host.upload_and_run(&mut board, &points);
    finish(&mut host, &mut board, points.len(), end);
    board.finish_trace();
    let vcd = vcd::read_changes(&trace).unwrap();
    assert_eq!(vcd.joint_position(0), i64::from(end[0]));
    let rises = vcd.rising_edges("step0");
    (rises[rises.len() - 1] - rises[0], rises)
}

#[test]
fn run_at_50_percent_takes_twice_as_long_and_ends_exact() {
    let (nominal, _) = run_span("speed100", None);
    let (slow, _) = run_span("speed50", Some(50));
    let ratio = slow as f64 / nominal as f64;
    println!(
        "run --speed 50: {:.4} s against {:.4} s nominal: x{ratio:.4}",
        slow as f64 * 1e-9,
        nominal as f64 * 1e-9
    );
    assert!((ratio - 2.0).abs() <= 0.04, "x{ratio}");
}

/// `run --speed 150` (OVERRIDE 150 before NEW) with joint 0's rate limit at 5,000
/// steps/s (LIMITS_SET) and a cruise at 4,000: the points lower the override to 125 %, so
/// no two rises are closer than the limit allows (before, the points were checked at
/// 100 % and the cruise ran at 6,000 steps/s), the cruise takes 1/1.25 of its nominal
/// time and the run ends exact.
#[test]
fn run_at_150_percent_is_held_to_the_joints_rate_limit() {
    let (_, nominal) = run_span("speed100b", None);
    let (mut board, trace) = board("speed150", TICK_HZ);
    let mut host = Host::new();
    let mut limits = protocol::JointLimits::NONE;
    limits.max_rate_hz = 5_000;
    host.ok(
        &mut board,
        &Command::LimitsSet(protocol::LimitsSet { joint: 0, limits }),
    );
    host.ok(&mut board, &Command::Override { percent: 150 });
    let (points, end) = trajectory(60);
    host.upload_and_run(&mut board, &points);
    finish(&mut host, &mut board, points.len(), end);
    let (_, motion) = stop_and_motion(&mut host, &mut board);
    board.finish_trace();
    let vcd = vcd::read_changes(&trace).unwrap();
    assert_eq!(vcd.joint_position(0), i64::from(end[0]));
    let rises = vcd.rising_edges("step0");
    let shortest = rises.windows(2).map(|w| w[1] - w[0]).min().unwrap();
    let fastest = 1e9 / shortest as f64;
    // The cruise: the 60 points of 40 steps after the ramp up (pulses 820..3220).
    let cruise = |r: &[u64]| (r[3220] - r[820]) as f64;
    let ratio = cruise(&nominal) / cruise(&rises);
    println!(
        "run --speed 150, joint 0 limited to 5,000 steps/s: override lowered to {} % \
         (refused joint {}, {:?}); fastest {fastest:.1} steps/s; cruise x{ratio:.4} as fast",
        motion.factor_percent, motion.refused_joint, motion.refused_limit
    );
    assert_eq!(motion.factor_percent, 125);
    assert!(fastest <= 5_000.0 * 1.001, "{fastest} steps/s");
    assert!((ratio - 1.25).abs() <= 0.01, "x{ratio}");
}

#[test]
fn override_25_mid_run_makes_the_rest_four_times_as_long_and_ends_exact() {
    let (_, nominal) = run_span("override100", None);
    let (mut board, trace) = board("override25", TICK_HZ);
    let mut host = Host::new();
    // A steep limit: the ramp from 100 to 25 % takes 1.5 ms (accel / speed = 500/s).
    accel_set(&mut host, &mut board, 2_000_000);
    let (points, end) = trajectory(60);
    host.upload_and_run(&mut board, &points);
    board.run_for(SECOND_NS / 2);
    let asked_ns = board.clock.now_ns();
    host.ok(&mut board, &Command::Override { percent: 25 });
    finish(&mut host, &mut board, points.len(), end);
    board.finish_trace();
    let vcd = vcd::read_changes(&trace).unwrap();
    assert_eq!(vcd.joint_position(0), i64::from(end[0]));
    let rises = vcd.rising_edges("step0");
    // Where it took effect: the first longer interval; the same pulse in the nominal run.
    let at = slowing_from(&rises, asked_ns).expect("a slow-down");
    let remaining = rises[rises.len() - 1] - rises[at];
    let nominal_remaining = nominal[nominal.len() - 1] - nominal[at];
    let ratio = remaining as f64 / nominal_remaining as f64;
    println!(
        "override 25 at 0.5 s: took effect {:.4} s after it was sent (pulse {at}); the rest \
         took {:.4} s against {:.4} s nominal: x{ratio:.4}",
        (rises[at] - asked_ns) as f64 * 1e-9,
        remaining as f64 * 1e-9,
        nominal_remaining as f64 * 1e-9
    );
    assert!((ratio - 4.0).abs() <= 0.08, "x{ratio}");
}

#[test]
fn stopped_during_a_hold_and_during_its_ramp_leaves_no_step_after_it() {
    for (name, after_hold_ns) in [("stop_ramp", SECOND_NS / 20), ("stop_held", SECOND_NS / 2)] {
        let (mut board, trace) = board(name, TICK_HZ);
        let mut host = Host::new();
        accel_set(&mut host, &mut board, ACCEL);
        let (points, _) = trajectory(400);
        host.upload_and_run(&mut board, &points);
        board.run_for(SECOND_NS);
        host.ok(&mut board, &Command::Hold);
        board.run_for(after_hold_ns);
        let sent_ns = board.clock.now_ns();
        let ack = host.ok(&mut board, &Command::Stopped);
        assert_eq!(ack.state, State::Stopped);
        let acked_ns = board.clock.now_ns();
        let stopped_at = board.motors.positions()[0];
        board.run_for(SECOND_NS);
        assert_eq!(board.motors.positions()[0], stopped_at, "{name}");
        board.finish_trace();
        let vcd = vcd::read_changes(&trace).unwrap();
        let changes = &vcd.changes["step0"];
        let (last_t, last_v) = changes.last().unwrap();
        println!(
            "{name}: STOPPED sent {:.3} s after HOLD; last STEP change {:.6} s before its ACK",
            after_hold_ns as f64 * 1e-9,
            acked_ns.saturating_sub(*last_t) as f64 * 1e-9
        );
        assert!(*last_t <= acked_ns, "{name}: STEP changed after the ACK");
        assert!(*last_t <= sent_ns + 1_000_000, "{name}: within 1 ms");
        assert_eq!(last_v, "0", "{name}: STEP left high");
    }
}

/// `n` points of 10 ms moving joints 0-5 by `steps` each from `from`.
fn six_joints(from: [i32; MAX_JOINTS], n: usize, steps: i32) -> Vec<Point> {
    let mut at = from;
    (0..n)
        .map(|_| {
            let before = at;
            for p in at.iter_mut().take(6) {
                *p += steps;
            }
            Point::from_motion(10_000, &before, &at)
        })
        .collect()
}

/// Points arriving during a run at `run --speed 50` past the warp budget (the NUCLEO's
/// 75,000 warped steps/s, which the simulator takes): six joints at 10,000 steps/s (60,000
/// together, 30,000 warped at 50 %), then points at 30,000 each (180,000, 90,000 at 50 %)
/// sent while it runs. The override is lowered to 41 % (73,800), MOTION names the whole
/// run and STEP_BUDGET, every point runs and every joint ends on its last point, and the
/// fast points' steps come at 41 % of their nominal rate. (Before, nothing checked points
/// that arrived during a warp: the run went on at 50 %, past the budget, where the NUCLEO's
/// step buffers run dry.)
#[test]
fn points_past_the_warp_budget_mid_run_lower_the_override_and_end_exact() {
    let (mut board, trace) = board("warp_budget", TICK_HZ);
    let mut host = Host::new();
    host.ok(&mut board, &Command::Override { percent: 50 });
    let slow = six_joints([0; MAX_JOINTS], 20, 100);
    let fast = six_joints(slow.last().unwrap().position, 60, 300);
    let end = fast.last().unwrap().position;
    host.ok(&mut board, &Command::New { count: 80 });
    for chunk in slow.chunks(protocol::MAX_POINTS_PER_FRAME) {
        host.ok(
            &mut board,
            &Command::Pending(protocol::PointList::Points(chunk)),
        );
    }
    host.ok(&mut board, &Command::Runing);
    board.run_for(SECOND_NS / 10);
    let sent_ns = board.clock.now_ns();
    for chunk in fast.chunks(protocol::MAX_POINTS_PER_FRAME) {
        host.ok(
            &mut board,
            &Command::Pending(protocol::PointList::Points(chunk)),
        );
    }
    finish(&mut host, &mut board, 80, end);
    let (_, motion) = stop_and_motion(&mut host, &mut board);
    board.finish_trace();
    let vcd = vcd::read_changes(&trace).unwrap();
    for (j, &at) in end.iter().enumerate().take(6) {
        assert_eq!(vcd.joint_position(j), i64::from(at), "joint {j}");
    }
    // Joint 0's rate over the fast points' middle (well after the ramp to 41 %).
    let rises = vcd.rising_edges("step0");
    let (a, b) = (2_000 + 300 * 20, 2_000 + 300 * 50);
    let rate = (b - a) as f64 / ((rises[b] - rises[a]) as f64 * 1e-9);
    println!(
        "run --speed 50, points at 180,000 steps/s together sent {:.3} s in: override \
         lowered to {} % (refused joint {:#x}, {:?}); joint 0 at {rate:.0} steps/s over its \
         fast points (nominal 30,000); every joint on its last point",
        sent_ns as f64 * 1e-9,
        motion.factor_percent,
        motion.refused_joint,
        motion.refused_limit
    );
    assert_eq!(
        (
            motion.factor_percent,
            motion.refused_joint,
            motion.refused_limit
        ),
        (41, 0xFF, Some(protocol::OverrideLimit::StepBudget))
    );
    assert!((rate / 30_000.0 - 0.41).abs() <= 0.005, "{rate} steps/s");
}
