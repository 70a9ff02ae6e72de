//! Issue 32, the wired e-stop input's category 1 in the simulator on virtual time (the
//! same firmware tasks and step producer as `sim-host --estop-input`; the input changed
//! as its signals change it, the edge handler's work in the caller): joint 0 at 4,000
//! steps/s with ACCEL_SET 20,000, ESTOP_CATEGORY 1, the input opened 2 s into the run:
//! - the STEP train slows along its path: no two consecutive intervals imply more than
//!   1.1 times the limit, about v^2/2a (400) steps from where the ramp took effect (the
//!   producer's committed periods first);
//! - the last step within v/a (0.2 s) + the lookahead (0.1 s) + 20 ms of the opening;
//! - then STOPPED latched, ENABLE off in STATUS (the drivers disabled), no edge after;
//!   RUNING refused ESTOP_LATCHED.
//!
//! Category 0 (the default) in the same run: the last edge at the opening (the handler's
//! halt), the drivers left enabled.
//!
//! The figures are printed (`--nocapture`).

mod virtual_host;

use armctl::vcd;
use protocol::{
    Command, ControlledStop, EStopCategory, MAX_JOINTS, MoreFlags, MotionFlags, Point, State,
    StatusCode, StatusFlags, StopCause,
};
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
/// `cruise` points at it, then down to rest.
fn trajectory(cruise: usize) -> Vec<Point> {
    let steps: Vec<i32> = (1..=CRUISE)
        .chain(std::iter::repeat_n(CRUISE, cruise))
        .chain((1..CRUISE).rev())
        .collect();
    let mut at = [0; MAX_JOINTS];
    steps
        .iter()
        .map(|&s| {
            let before = at;
            at[0] += s;
            Point::from_motion(10_000, &before, &at)
        })
        .collect()
}

/// Steps/s^2 two consecutive intervals imply, the highest over rises from `from` (ns).
fn max_implied_accel(rises: &[u64], from: u64) -> f64 {
    let window: Vec<u64> = rises.iter().copied().filter(|&t| t >= from).collect();
    window
        .windows(3)
        .map(|w| {
            let i1 = (w[1] - w[0]) as f64 * 1e-9;
            let i2 = (w[2] - w[1]) as f64 * 1e-9;
            (1.0 / i2 - 1.0 / i1).abs() / ((i1 + i2) / 2.0)
        })
        .fold(0.0, f64::max)
}

/// The first rise at or after `from` whose interval is longer than the cruise's: where the
/// ramp took effect (after the periods the producer had committed).
fn slowing_from(rises: &[u64], from: u64) -> Option<usize> {
    rises
        .windows(2)
        .position(|w| w[0] >= from && w[1] - w[0] > INTERVAL_NS + 100)
}

/// A run 2 s in with joint 0 at cruise, the category set; the opening's time, ns.
fn open_during_run(name: &str, category: EStopCategory) -> (VirtualBoard, Host, u64) {
    let (mut board, _trace) = board(name, TICK_HZ);
    let mut host = Host::new();
    host.ok(
        &mut board,
        &Command::AccelSet {
            joint: 0,
            max_accel_steps_s2: ACCEL,
        },
    );
    host.ok(&mut board, &Command::EstopCategory(category));
    host.upload_and_run(&mut board, &trajectory(400));
    board.run_for(2 * SECOND_NS);
    let open_ns = board.clock.now_ns();
    board.set_estop_input(true);
    (board, host, open_ns)
}

#[test]
fn category_1_ramps_within_the_acceleration_then_disables_the_drivers() {
    let (mut board, mut host, open_ns) = open_during_run("estop_cat1", EStopCategory::Controlled);
    let status = host.status(&mut board);
    assert!(
        status.more_flags.has(MoreFlags::ESTOP_LATCHED),
        "latched at once"
    );
    let stopped = run_until_stopped(&mut board, 2 * SECOND_NS);
    let stopped_ns = board.clock.now_ns();
    assert_eq!(stopped.state, State::Stopped as u8);
    // One more second: nothing moves.
    board.run_for(SECOND_NS);
    let status = host.status(&mut board);
    assert_eq!(status.state, State::Stopped);
    assert!(
        !status.flags.has(StatusFlags::DRIVERS_ENABLED),
        "ENABLE off: {status:?}"
    );
    assert!(status.more_flags.has(MoreFlags::ESTOP_LATCHED));
    let ack = host.command(&mut board, &Command::Runing);
    assert_eq!(ack.status, StatusCode::EstopLatched);
    let (cause, motion) = stop_and_motion(&mut host, &mut board);
    assert_eq!(motion.last_stop, Some(ControlledStop::EStop));
    assert_eq!(motion.estop_category, Some(EStopCategory::Controlled));
    assert!(!motion.flags.has(MotionFlags::ESTOP_RAMP));
    assert_eq!(cause.cause, Some(StopCause::EstopInput));
    board.finish_trace();

    let trace = scratch("estop_cat1.vcd");
    let vcd = vcd::read_changes(&trace).unwrap();
    let rises = vcd.rising_edges("step0");
    let after: Vec<u64> = rises.iter().copied().filter(|&t| t >= open_ns).collect();
    let last = *after.last().expect("steps after the opening");
    let to_rest = (last - open_ns) as f64 * 1e-9;
    let ratio =
        max_implied_accel(&rises, open_ns.saturating_sub(SECOND_NS / 10)) / f64::from(ACCEL);
    let drivers_off = (stopped_ns.saturating_sub(last)) as f64 * 1e-9;
    let ramp = slowing_from(&rises, open_ns).expect("a slow-down");
    let ramp_ns = rises[ramp];
    let ramp_steps = rises[ramp + 1..].iter().filter(|&&t| t <= last).count();
    println!(
        "category 1, opened 2 s into the run: last step {to_rest:.4} s after the opening \
         (bound v/a + lookahead + 20 ms = {:.3} s); the ramp began {:.4} s after it; {} \
         steps after the opening, {ramp_steps} from the ramp's start (v^2/2a = 400); max \
         implied acceleration / limit {ratio:.4}; STOPPED with the drivers off reported \
         {drivers_off:.4} s after the last step",
        0.2 + LOOKAHEAD_S + 0.02,
        (ramp_ns - open_ns) as f64 * 1e-9,
        after.len(),
    );
    assert!(to_rest <= 0.2 + LOOKAHEAD_S + 0.02, "{to_rest} s to rest");
    assert!((395..=405).contains(&ramp_steps), "{ramp_steps} steps");
    assert!(ratio <= 1.1, "{ratio} x the limit");
    assert!(
        rises.iter().all(|&t| t <= last),
        "no edge after the standstill"
    );
}

#[test]
fn category_0_stops_at_the_opening_and_leaves_the_drivers() {
    let (mut board, mut host, open_ns) = open_during_run("estop_cat0", EStopCategory::Instant);
    run_until_stopped(&mut board, SECOND_NS);
    board.run_for(SECOND_NS / 2);
    let status = host.status(&mut board);
    assert!(status.flags.has(StatusFlags::DRIVERS_ENABLED), "{status:?}");
    assert!(status.more_flags.has(MoreFlags::ESTOP_LATCHED));
    board.finish_trace();
    let vcd = vcd::read_changes(&scratch("estop_cat0.vcd")).unwrap();
    let rises = vcd.rising_edges("step0");
    let late: Vec<u64> = rises.iter().copied().filter(|&t| t > open_ns).collect();
    println!(
        "category 0: {} STEP rises after the opening (the handler halted the steps)",
        late.len()
    );
    assert!(late.is_empty(), "edges after the opening: {late:?}");
}
