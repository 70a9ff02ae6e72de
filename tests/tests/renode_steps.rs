//! STEP and DIR of the NUCLEO-H743ZI2 firmware itself (the `cargo fw` ELF) on Renode, with
//! the step path's models (`tests/renode/step-path.resc`: the joint timers with their update
//! DMA requests and DCR/DMAR burst, DMAMUX1, DMA1's and DMA2's circular streams with
//! half/complete interrupts and a time per item served by RM0433's arbitration (issue 34),
//! all from RM0433; an edge recorder on the STEP and DIR pins). The QEMU tests'
//! trajectories are uploaded over the emulated Ethernet (`tests/tests/qemu.rs`: the same
//! sweeps), and what the pins did is compared with arm-step's oracle (`StepEngine`, which
//! `firmware/step/tests/producer.rs` compares with the producer on 10 M pulses):
//!
//! - every rising STEP edge of every joint at the oracle's tick, counted from its own timer's
//!   start (CR1.CEN), with one offset for all joints (the run's lead-in, which the firmware
//!   picks); each pulse as wide as the profile says (the one under way at an e-stop at
//!   least that: the stop lets it end at its own CCR1, `renode_stop_pulse.rs`);
//! - DIR changed only while STEP is low, after the joint's last pulse fell, and at least the
//!   drivers' DIR setup before the next rise; the pulses signed by DIR sum to the move;
//! - after an e-stop mid-run, the positions the board reports are the signed pulses its pins
//!   made, the pulses made are the oracle's up to the stop, and nothing moves after;
//! - under a STATUS flood while a keyed owner streams, each of 20 single STOPPEDs halts the
//!   arm; the time from its landing at the MAC (the recorder is also a probe on the switch)
//!   to the last STEP edge is printed (issue 30).
//!
//! Times: the models make every timer edge at its exact tick in Renode's virtual time (ns),
//! so the STEP comparison is exact. DIR is written by the CPU (TIM13's compare interrupt), so
//! its time is the instruction's in Renode's CPU model (`PerformanceInMips`, not the
//! Cortex-M7's pipeline): the DIR margins printed are the emulator's, not the chip's.
//!
//! Needs Renode (`renode` on PATH or `RENODE`; the prebuilt one needs mono) and root; without
//! them every test prints what it needs and passes.

mod common;

use std::sync::Arc;
use std::time::{Duration, Instant};

use arm_core::profile::{BoardProfile, NUCLEO_H743ZI2, NUCLEO_H743ZI2_TMC};
use arm_step::{JointMask, MAX_JOINTS, RATE_ONE, Segment, StepEngine, StepPins, Warp};
use armctl::{Error, Options, RunEnd, RunOptions};
use common::{assert_stays_put, run_reporting_progress_with, stop_mid_run, sweep};
use protocol::{MotionFlags, Point, State, StatusFlags};
use system_tests::renode::{
    BOARD, EMULATED_TIMER_HZ, Edge, HOSTS, RenodeBoard, STOPPED_LANDED, malformed_flood,
};
use system_tests::renode::{emulated, emulated_eight_joints};
use system_tests::require_renode;

/// Prints a figure to the real stderr (seen without --nocapture).
fn note(text: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr().lock(), "renode steps: {text}");
}

/// Joints the board drives with erased settings.
const JOINTS: usize = 6;

/// Virtual nanoseconds per timer tick in the emulator.
const NS_PER_TICK: u64 = 1_000_000_000 / EMULATED_TIMER_HZ;

/// The emulated CPU at the instruction rate the profile's DIR budget assumes (the Cortex-M7
/// at 400 MHz, one instruction a cycle: `dir_latency_ns`'s reason), for the tests that hold
/// DIR timing to that budget. Renode's default is 100 MIPS.
const CHIP_MIPS: &str = "sysbus.cpu PerformanceInMips 400";

/// What one joint's lines did, in its timer's ticks from its (last) CR1.CEN.
#[derive(Debug, Default)]
struct Joint {
    /// Virtual time of the timer's start (its tick 0).
    start_ns: u64,
    rises: Vec<u64>,
    falls: Vec<u64>,
    /// DIR changes (tick, possibly before the start: signed) and the level after.
    dirs: Vec<(i64, bool)>,
    /// DIR's level before the first change after the start.
    dir_at_start: bool,
    /// A STEP edge that was not on the timer's tick grid (ns since the start).
    off_grid: Vec<u64>,
    /// The pulse (index into `rises`) that was high when a stop froze the counter: it falls
    /// at its CCR1 after the stop resumed the counter (`step_dma/stop.rs`), off the grid by
    /// the freeze, at least as wide as the others (its fall is recorded rounded up).
    under_way_at_stop: Option<usize>,
    /// STEP high when the record ends.
    high_at_end: bool,
}

/// The recorder's edges, also written to `RENODE_EDGES_COPY` if set (the board's folder goes
/// with the board), as `<ns> <line> <level>` lines.
fn recorded(board: &RenodeBoard) -> Vec<Edge> {
    let edges = board.edges();
    if let Some(path) = std::env::var_os("RENODE_EDGES_COPY") {
        let text: String = edges
            .iter()
            .map(|e| format!("{} {} {}\n", e.ns, e.line, u8::from(e.high)))
            .collect();
        std::fs::write(path, text).expect("RENODE_EDGES_COPY");
    }
    edges
}

/// Splits the recorder's edges into joints, from each joint timer's last start. A counting
/// line rising while the joint's STEP is high is not a start: it is a stop resuming the
/// counter of a pulse under way (`step_dma/stop.rs` resumes only then), where a run's start
/// always finds STEP low (its first period has no pulse).
fn joints(edges: &[Edge]) -> [Joint; MAX_JOINTS] {
    std::array::from_fn(|j| {
        let counting = || edges.iter().filter(|e| usize::from(e.line) == 16 + j);
        let mut start_ns = 0;
        let mut step_high = false;
        for e in edges {
            let line = usize::from(e.line);
            if line == j {
                step_high = e.high;
            } else if line == 16 + j && e.high && !step_high {
                start_ns = e.ns;
            }
        }
        // The counter's first freeze after the start: a stop's, or the run's end.
        let freeze_ns = counting()
            .find(|e| !e.high && e.ns > start_ns)
            .map(|e| e.ns);
        let mut joint = Joint {
            start_ns,
            ..Joint::default()
        };
        let mut dir;
        let mut high = false;
        for e in edges {
            let line = usize::from(e.line);
            if line == 8 + j {
                if e.ns <= start_ns {
                    dir = e.high;
                    joint.dir_at_start = dir;
                } else {
                    dir = e.high;
                }
                let tick = (i64::try_from(e.ns).unwrap() - i64::try_from(start_ns).unwrap())
                    / i64::try_from(NS_PER_TICK).unwrap();
                if e.ns > start_ns {
                    joint.dirs.push((tick, dir));
                }
            }
            if line == j && e.ns >= start_ns {
                let since = e.ns - start_ns;
                let after_freeze = freeze_ns.is_some_and(|f| e.ns >= f);
                if after_freeze && !e.high && high && joint.under_way_at_stop.is_none() {
                    joint.under_way_at_stop = Some(joint.rises.len() - 1);
                    joint.falls.push(since.div_ceil(NS_PER_TICK));
                    high = false;
                    continue;
                }
                if since % NS_PER_TICK != 0 {
                    joint.off_grid.push(since);
                }
                if e.high {
                    joint.rises.push(since / NS_PER_TICK);
                } else if high {
                    joint.falls.push(since / NS_PER_TICK);
                }
                high = e.high;
            }
        }
        joint.high_at_end = high;
        joint
    })
}

/// [`joints`] on a record made by hand (no Renode): a run's start, two pulses, a stop that
/// froze the counter while the second was high and resumed it (the pulse falling off the
/// grid, after its width), then a later run's reset and start. Each run is found from its
/// own start and the resumed pulse is the one under way, its fall rounded up.
#[test]
fn joints_take_a_stops_resume_for_no_run_start() {
    let width = u64::from(NUCLEO_H743ZI2.step_timing().pulse_width_ticks) * NS_PER_TICK;
    let e = |ns, line, high| Edge { ns, line, high };
    let first_run = [
        e(1_000, 16, true),
        e(11_000, 0, true),
        e(11_000 + width, 0, false),
        e(21_000, 0, true),
        // The stop: frozen 300 ns into the pulse, resumed 50 ns later.
        e(21_300, 16, false),
        e(21_350, 16, true),
        e(21_050 + width, 0, false),
    ];
    let board = joints(&first_run);
    assert_eq!(
        board[0].start_ns, 1_000,
        "the resume was taken for the start"
    );
    assert_eq!(board[0].rises, [10_000 / NS_PER_TICK, 20_000 / NS_PER_TICK]);
    assert_eq!(board[0].under_way_at_stop, Some(1));
    assert!(board[0].off_grid.is_empty(), "{:?}", board[0].off_grid);
    assert_eq!(
        board[0].falls[1] - board[0].rises[1],
        (width + 50).div_ceil(NS_PER_TICK)
    );
    assert!(!board[0].high_at_end);
    // The next run: the timer's reset (counting falls) and its start with STEP low.
    let mut two_runs = first_run.to_vec();
    two_runs.extend([
        e(90_000, 16, false),
        e(90_400, 16, true),
        e(100_400, 0, true),
        e(100_400 + width, 0, false),
    ]);
    let board = joints(&two_runs);
    assert_eq!(board[0].start_ns, 90_400);
    assert_eq!(board[0].rises, [10_000 / NS_PER_TICK]);
    assert_eq!(board[0].under_way_at_stop, None);
}

/// The net steps of `joint`: its rises signed by DIR at each (DIR high = positive).
fn signed_pulses(joint: &Joint) -> i32 {
    let mut dir = joint.dir_at_start;
    let mut changes = joint.dirs.iter().peekable();
    let mut net = 0;
    for &rise in &joint.rises {
        while let Some(&&(tick, level)) = changes.peek() {
            if tick > i64::try_from(rise).unwrap() {
                break;
            }
            dir = level;
            changes.next();
        }
        net += if dir { 1 } else { -1 };
    }
    net
}

/// The segments the controller hands its step producer for `points` from `start` (arm-core's
/// `runs.rs`: each point's duration and the step difference from the previous position).
fn segments(start: [i32; MAX_JOINTS], points: &[Point]) -> Vec<Segment> {
    let mut at = start;
    points
        .iter()
        .map(|p| {
            let steps = std::array::from_fn(|j| p.position[j] - at[j]);
            at = p.position;
            Segment {
                duration_us: u32::try_from(p.duration).unwrap(),
                steps,
            }
        })
        .collect()
}

/// What arm-step's engine (the oracle) does for some segments from tick 0 (the default
/// build's profile, or the `tmc-drivers` build's: [`oracle_of`]).
struct Oracle {
    /// Rising STEP edges per joint.
    rises: [Vec<u64>; MAX_JOINTS],
    /// DIR changes per joint (tick, level), the levels set at tick 0 included.
    dirs: [Vec<(u64, bool)>; MAX_JOINTS],
}

impl std::ops::Index<usize> for Oracle {
    type Output = Vec<u64>;
    fn index(&self, joint: usize) -> &Vec<u64> {
        &self.rises[joint]
    }
}

/// The oracle's edges for `segments` from tick 0, on the default build.
fn oracle(segments: &[Segment]) -> Oracle {
    oracle_of(&NUCLEO_H743ZI2, segments)
}

/// The oracle's edges for `segments` from tick 0, on the build with `profile`.
fn oracle_of(profile: &BoardProfile, segments: &[Segment]) -> Oracle {
    oracle_warped(profile, segments, Warp::IDENTITY)
}

/// The oracle's edges for `segments` from tick 0 under `warp` (issue 32: HOLD, RESUME and
/// OVERRIDE as rate changes on the oracle's clock), on the build with `profile`.
fn oracle_warped(profile: &BoardProfile, segments: &[Segment], warp: Warp) -> Oracle {
    struct Rises {
        now: u64,
        rises: [Vec<u64>; MAX_JOINTS],
        dirs: [Vec<(u64, bool)>; MAX_JOINTS],
    }
    impl StepPins for Rises {
        fn set_direction(&mut self, joint: usize, positive: bool) {
            self.dirs[joint].push((self.now, positive));
        }
        fn step_high(&mut self, joints: JointMask) {
            for (j, rises) in self.rises.iter_mut().enumerate() {
                if joints & (1 << j) != 0 {
                    rises.push(self.now);
                }
            }
        }
        fn step_low(&mut self, _joints: JointMask) {}
    }
    let mut engine = StepEngine::<64>::new(profile.step_timing());
    assert!(engine.set_warp(warp));
    let mut pending = segments.iter().copied().peekable();
    let mut fill = |engine: &mut StepEngine<64>| {
        while engine.free_slots() > 0 {
            let Some(s) = pending.next() else { break };
            engine.push(s).unwrap();
        }
    };
    fill(&mut engine);
    engine.start(0);
    let mut lines = Rises {
        now: 0,
        rises: Default::default(),
        dirs: Default::default(),
    };
    let mut deadline = Some(0);
    while let Some(now) = deadline {
        lines.now = now;
        deadline = engine.poll(now, &mut lines).next_deadline;
        fill(&mut engine);
    }
    Oracle {
        rises: lines.rises,
        dirs: lines.dirs,
    }
}

/// How late each DIR change on the pins came after the oracle's (ticks, the lead-in
/// `offset` applied): the step clock's alarm and TIM13's interrupt as the emulator runs
/// them. Panics if one came early or was missed. (least, greatest, count)
fn dir_lateness(board: &[Joint; MAX_JOINTS], oracle: &Oracle, offset: i64) -> (i64, i64, usize) {
    let (mut least, mut most, mut count) = (i64::MAX, i64::MIN, 0);
    for (j, pins) in board.iter().enumerate() {
        // The changes after tick 0 (those at 0 are made before the timers start).
        let expected: Vec<(i64, bool)> = oracle.dirs[j]
            .iter()
            .filter(|(t, _)| *t > 0)
            .map(|&(t, level)| (i64::try_from(t).unwrap() + offset, level))
            .collect();
        // The engine reports every call, the pins only changes: compare changes.
        let mut level = pins.dir_at_start;
        let expected: Vec<(i64, bool)> = expected
            .into_iter()
            .filter(|&(_, l)| {
                let changed = l != level;
                level = l;
                changed
            })
            .collect();
        assert_eq!(
            pins.dirs.len(),
            expected.len(),
            "joint {j}: DIR changes on the pin {:?}, the oracle's {expected:?}",
            pins.dirs
        );
        for (&(got, level), &(want, want_level)) in pins.dirs.iter().zip(&expected) {
            assert_eq!(level, want_level, "joint {j}: DIR level at tick {got}");
            let late = got - want;
            assert!(late >= 0, "joint {j}: DIR changed {} ticks early", -late);
            least = least.min(late);
            most = most.max(late);
            count += 1;
        }
    }
    (least, most, count)
}

/// The offset (ticks) that puts the oracle's first rise on the board's, from the first joint
/// that moved.
fn lead_in(board: &[Joint; MAX_JOINTS], oracle: &Oracle) -> i64 {
    (0..MAX_JOINTS)
        .find_map(|j| {
            let b = *board[j].rises.first()?;
            let o = *oracle[j].first()?;
            Some(i64::try_from(b).unwrap() - i64::try_from(o).unwrap())
        })
        .expect("no joint made a pulse")
}

/// Checks every joint's rises against the oracle's shifted by `offset`: all of them
/// (`whole`), or the board's as a prefix of the oracle's (a run cut by a stop).
fn assert_rises_match(board: &[Joint; MAX_JOINTS], oracle: &Oracle, offset: i64, whole: bool) {
    for j in 0..MAX_JOINTS {
        let expected: Vec<u64> = oracle[j]
            .iter()
            .map(|&t| u64::try_from(i64::try_from(t).unwrap() + offset).unwrap())
            .collect();
        let got = &board[j].rises;
        let compared = if whole { expected.len() } else { got.len() };
        assert!(
            got.len() == compared && compared <= expected.len(),
            "joint {j}: {} rising edges on the pin, the oracle has {} ({})",
            got.len(),
            expected.len(),
            if whole { "whole run" } else { "up to the stop" }
        );
        if let Some(k) = (0..compared).find(|&k| got[k] != expected[k]) {
            panic!(
                "joint {j}: rise {k} at tick {} on the pin, the oracle's at {} (offset {offset}); \
                 pin {:?}.., oracle {:?}..",
                got[k],
                expected[k],
                &got[k.saturating_sub(2)..(k + 3).min(got.len())],
                &expected[k.saturating_sub(2)..(k + 3).min(expected.len())]
            );
        }
    }
}

/// Pulse width and DIR timing on every joint; returns the smallest DIR setup seen (ticks
/// from a DIR change to the next rise) and the smallest gap from a fall to a DIR change.
fn assert_pulse_and_dir_timing(board: &[Joint; MAX_JOINTS]) -> (Option<i64>, Option<i64>) {
    assert_pulse_and_dir_timing_of(&NUCLEO_H743ZI2, board)
}

/// [`assert_pulse_and_dir_timing`] for the build with `profile`.
fn assert_pulse_and_dir_timing_of(
    profile: &BoardProfile,
    board: &[Joint; MAX_JOINTS],
) -> (Option<i64>, Option<i64>) {
    let timing = profile.step_timing();
    // The drivers' own setup (without the latency budget the producer adds for the
    // interrupt): the least a driver needs.
    let driver_setup =
        i64::from(profile.driver.dir_setup_ns) * i64::from(timing.tick_hz) / 1_000_000_000;
    let (mut least_setup, mut least_after_fall) = (None::<i64>, None::<i64>);
    for (j, joint) in board.iter().enumerate() {
        assert!(
            joint.off_grid.is_empty(),
            "joint {j}: STEP edges off the timer's tick grid (ns after its start): {:?}",
            &joint.off_grid[..joint.off_grid.len().min(5)]
        );
        assert!(!joint.high_at_end, "joint {j}: STEP left high");
        assert_eq!(joint.falls.len(), joint.rises.len(), "joint {j}");
        for (k, (rise, fall)) in joint.rises.iter().zip(&joint.falls).enumerate() {
            if joint.under_way_at_stop == Some(k) {
                assert!(
                    fall - rise >= u64::from(timing.pulse_width_ticks),
                    "joint {j}: the pulse under way at the stop (tick {rise}) was cut to {} \
                     ticks",
                    fall - rise
                );
                continue;
            }
            assert_eq!(
                fall - rise,
                u64::from(timing.pulse_width_ticks),
                "joint {j}: pulse at tick {rise}"
            );
        }
        for &(tick, _) in &joint.dirs {
            let next_rise = joint
                .rises
                .iter()
                .map(|&r| i64::try_from(r).unwrap())
                .find(|&r| r > tick);
            let last_fall = joint
                .falls
                .iter()
                .map(|&f| i64::try_from(f).unwrap())
                .rfind(|&f| f <= tick);
            let last_rise = joint
                .rises
                .iter()
                .map(|&r| i64::try_from(r).unwrap())
                .rfind(|&r| r <= tick);
            if let Some(rise) = last_rise {
                let fall = last_fall.unwrap_or(-1);
                assert!(
                    fall >= rise,
                    "joint {j}: DIR changed at tick {tick} while STEP was high (rose at {rise})"
                );
                least_after_fall =
                    Some(least_after_fall.map_or(tick - fall, |m| m.min(tick - fall)));
            }
            if let Some(rise) = next_rise {
                assert!(
                    rise - tick >= driver_setup,
                    "joint {j}: DIR changed at tick {tick}, {} ticks before the next rise (the \
                     drivers need {driver_setup})",
                    rise - tick
                );
                least_setup = Some(least_setup.map_or(rise - tick, |m| m.min(rise - tick)));
            }
        }
    }
    (least_setup, least_after_fall)
}

/// The steps `points` ask of every joint from `start` (out and back counts both ways).
fn steps_asked(start: [i32; MAX_JOINTS], points: &[Point]) -> [usize; MAX_JOINTS] {
    let mut steps = [0; MAX_JOINTS];
    let mut at = start;
    for point in points {
        for (j, s) in steps.iter_mut().enumerate() {
            *s += point.position[j].abs_diff(at[j]) as usize;
        }
        at = point.position;
    }
    steps
}

fn position(board: &RenodeBoard, arm: &armctl::Client) -> [i32; MAX_JOINTS] {
    arm.current_location(Duration::from_secs(5))
        .unwrap_or_else(|e| panic!("a LOCATION report: {e}\n{}", board.log()))
        .position
}

/// No timer model handled an event after its time (`LateEvents`, read over the monitor).
fn assert_no_late_events(board: &RenodeBoard) {
    for timer in [
        "stepTim2",
        "stepTim5",
        "stepTim3",
        "stepTim4",
        "stepTim1",
        "stepTim8",
        "stepTim16",
        "stepTim17",
        "stepClockTim13",
    ] {
        let answer = board.monitor(&format!("sysbus.{timer} LateEvents"));
        let late = answer
            .split_whitespace()
            .find_map(|t| t.strip_prefix("0x"))
            .and_then(|t| u64::from_str_radix(t, 16).ok());
        assert_eq!(late, Some(0), "{timer} LateEvents: {answer:?}");
    }
}

/// A number the monitor printed for `command` (the first `0x..`), if any.
fn monitor_value(board: &RenodeBoard, command: &str) -> Option<u64> {
    board
        .monitor(command)
        .split_whitespace()
        .find_map(|t| t.strip_prefix("0x"))
        .and_then(|t| u64::from_str_radix(t, 16).ok())
}

/// No joint timer's update event came while its last DMA burst was still open (the DMA
/// model's time per item: a late burst replays the period before, `LateBursts`).
fn assert_no_late_bursts(board: &RenodeBoard) {
    for (joint, timer) in JOINT_TIMERS.iter().enumerate() {
        let late = monitor_value(board, &format!("sysbus.{timer} LateBursts"));
        assert_eq!(late, Some(0), "joint {joint} ({timer}): late DMA bursts");
    }
}

/// The joint timers' models, joint order (step-path.resc).
const JOINT_TIMERS: [&str; MAX_JOINTS] = [
    "stepTim2",
    "stepTim5",
    "stepTim3",
    "stepTim4",
    "stepTim1",
    "stepTim8",
    "stepTim16",
    "stepTim17",
];

/// Each joint's DMA model and stream (firmware/board/src/step_dma: joints 0-3, the APB1
/// timers, on DMA1 streams 0-3; joints 4-7, the APB2 timers, on DMA2 streams 0-3).
fn joint_stream(joint: usize) -> (&'static str, usize) {
    (if joint < 4 { "stepDma1" } else { "stepDma2" }, joint % 4)
}

/// The longest wait (ns, virtual) of any item of each joint's stream for the DMA model.
fn longest_dma_waits(board: &RenodeBoard) -> Vec<Option<u64>> {
    (0..MAX_JOINTS)
        .map(|j| {
            let (dma, stream) = joint_stream(j);
            monitor_value(
                board,
                &format!("sysbus.{dma} LongestWaitNanoseconds {stream}"),
            )
        })
        .collect()
}

/// `count` points of `duration_us` from `start`, joint `j` moving `steps[j]` steps in each
/// (a constant rate per joint: `steps[j]` per `duration_us`).
fn constant_rates(
    start: [i32; MAX_JOINTS],
    steps: [i32; MAX_JOINTS],
    count: usize,
    duration_us: i32,
) -> Vec<Point> {
    let mut at = start;
    (0..count)
        .map(|_| {
            let mut next = at;
            for (p, s) in next.iter_mut().zip(steps) {
                *p += s;
            }
            let point = Point::from_motion(duration_us, &at, &next);
            at = next;
            point
        })
        .collect()
}

/// Runs `steps` per 1 ms point for 6 ms (after a slow first millisecond) on all 8 joints of the `tmc-drivers` build at the
/// chip's instruction rate, and checks every edge against the oracle (every rise at its
/// tick, no late event, no late DMA burst). Prints the DMA models' longest waits.
fn eight_joints_run(name: &str, steps: [i32; MAX_JOINTS]) {
    let mut board = RenodeBoard::start_tmc_with_step_path(CHIP_MIPS);
    let arm = board.connect_from(HOSTS[0], emulated_eight_joints());
    arm.set_joints(8).unwrap();
    arm.set_location(&[0; MAX_JOINTS]).unwrap();
    let start = position(&board, &arm);
    // A slow first millisecond (1/40 of the rates): its first pulses come long after the DIR
    // setup, where the oracle (which starts its segments at tick 0, with the DIR change)
    // and the board (which sets DIR before its timers start) place them alike.
    let mut points = constant_rates(start, steps.map(|s| (s / 40).max(1)), 1, 1_000);
    points.extend(constant_rates(points[0].position, steps, 6, 1_000));
    let began = Instant::now();
    let options = RunOptions {
        stall_timeout: Duration::from_secs(120),
        completion_timeout: Some(Duration::from_secs(600)),
        ..RunOptions::default()
    };
    let report = arm
        .run_trajectory(&points, &options, |_| {})
        .unwrap_or_else(|e| panic!("{e}\n{}", board.log()));
    let status = report.final_status.unwrap();
    assert_eq!(status.state, State::Stopped);
    assert_eq!(usize::from(status.executed), points.len());
    assert!(!status.flags.has(StatusFlags::UNDERRUN), "{status:?}");
    let end = position(&board, &arm);
    assert_eq!(end, points.last().unwrap().position);
    let wall = began.elapsed().as_secs_f64();
    let waits = longest_dma_waits(&board);
    let run = assert_run_is_the_oracles_of(&NUCLEO_H743ZI2_TMC, &board, start, end, &points);
    assert_no_late_bursts(&board);
    for (j, steps) in steps.iter().enumerate() {
        let asked = 6 * steps + (steps / 40).max(1);
        assert_eq!(run.pins[j].rises.len(), asked as usize, "joint {j}: rises");
    }
    note(&format!(
        "{name}: rising STEP edges per joint {:?}, each at the oracle's tick, no late DMA \
         burst; longest DMA wait per joint's stream {waits:?} ns (virtual, 4 ns a tick: \
         the shortest period is 800 ns); {wall:.1} s of wall time",
        run.counts()
    ));
    board.assert_healthy();
}

/// Joint 7 (TIM17, the last stream of its DMA controller, RM0433's arbitration serves it
/// after every other very-high stream) at the `tmc-drivers` build's top rate, 1 MHz: 200-tick
/// periods, the profile's DMA period floor (`min_dma_period_ns`), beside joints 0-6 at
/// 400 kHz (3.8 MHz in all, within the 4 MHz step budget): every 1,000 ticks all eight
/// bursts come at once. Every rise at the oracle's tick, on joints 6-7 (TIM16/17) too.
///
/// Failed before the streams were split over DMA1 and DMA2 (issue 34): with all eight on
/// DMA2 at 40 ns an item, joint 7's burst waited for 21 words and landed 960 ns after its
/// update event, after its next (800 ns); that update replayed the period before: an extra
/// pulse on joint 7 that neither the producer nor NDTR counted.
#[test]
fn joint_7_at_its_top_rate_beside_seven_slower_joints_keeps_the_oracles_ticks() {
    require_renode!();
    eight_joints_run(
        "joint 7 at 1 MHz, joints 0-6 at 400 kHz",
        [400, 400, 400, 400, 400, 400, 400, 1_000],
    );
}

/// All 8 joints in step (the same rate and phase, so every period's eight bursts come at
/// the same instant) at 500 kHz each: the whole 4 MHz step budget (the `tmc-drivers`
/// period floor of 1 us is 1 MHz a joint, which the budget gives one joint at a time).
/// Every rise at the oracle's tick on all 8 joints.
#[test]
fn eight_joints_in_step_keep_the_oracles_ticks() {
    require_renode!();
    eight_joints_run("8 joints in step at 500 kHz", [500; MAX_JOINTS]);
}

fn ticks_us(ticks: i64) -> f64 {
    // In the firmware's ticks (200 MHz on the chip).
    ticks as f64 * 1e6 / f64::from(NUCLEO_H743ZI2.step_timer_hz)
}

/// The QEMU test's run (`run_reaches_the_last_point_and_executes_every_point`): 120 points of
/// 10 ms, six joints out and back (one reversal each), from a set location.
/// What a whole run's pins showed against the oracle, once every check passed.
struct RunEdges {
    pins: [Joint; MAX_JOINTS],
    oracle: Oracle,
    /// Lead-in: the oracle's ticks shifted onto the board's.
    offset: i64,
    /// Least DIR setup before the next rise, least time after the last fall (ticks).
    setup: Option<i64>,
    after_fall: Option<i64>,
    /// DIR changes, and how late the least and the most late came after the oracle's.
    dir_changes: usize,
    least_late: i64,
    most_late: i64,
}

impl RunEdges {
    fn counts(&self) -> Vec<usize> {
        self.pins.iter().map(|p| p.rises.len()).collect()
    }

    fn oracle_counts(&self) -> Vec<usize> {
        self.oracle.rises.iter().map(Vec::len).collect()
    }
}

/// The checks every whole run gets: each rise at the oracle's tick, pulse width and DIR
/// timing, the pulses signed by DIR summing to the move from `start` to `end`, DIR changes
/// within the budget, and no event the models saw late.
fn assert_run_is_the_oracles(
    board: &RenodeBoard,
    start: [i32; MAX_JOINTS],
    end: [i32; MAX_JOINTS],
    points: &[Point],
) -> RunEdges {
    assert_run_is_the_oracles_of(&NUCLEO_H743ZI2, board, start, end, points)
}

/// [`assert_run_is_the_oracles`] for the build with `profile`.
fn assert_run_is_the_oracles_of(
    profile: &BoardProfile,
    board: &RenodeBoard,
    start: [i32; MAX_JOINTS],
    end: [i32; MAX_JOINTS],
    points: &[Point],
) -> RunEdges {
    let pins = joints(&recorded(board));
    let oracle = oracle_of(profile, &segments(start, points));
    let offset = lead_in(&pins, &oracle);
    assert_rises_match(&pins, &oracle, offset, true);
    let (setup, after_fall) = assert_pulse_and_dir_timing_of(profile, &pins);
    for j in 0..MAX_JOINTS {
        assert_eq!(
            signed_pulses(&pins[j]),
            end[j] - start[j],
            "joint {j}: net pulses"
        );
    }
    let (least_late, most_late, dir_changes) = dir_lateness(&pins, &oracle, offset);
    assert_no_late_events(board);
    RunEdges {
        pins,
        oracle,
        offset,
        setup,
        after_fall,
        dir_changes,
        least_late,
        most_late,
    }
}

#[test]
fn a_run_makes_the_oracles_edges_on_the_pins() {
    require_renode!();
    let mut board = RenodeBoard::start_with_step_path("");
    let arm = board.connect_from(HOSTS[0], emulated());
    arm.set_location(&[100, -200, 300, 0, 0, 0]).unwrap();
    let start = position(&board, &arm);
    assert_eq!(&start[..3], &[100, -200, 300]);
    let points = sweep(start, JOINTS, 120, 4, 10_000);
    let began = Instant::now();
    // armctl's default stall wait is 12 s of wall time. Since the DMA models take time per
    // item (issue 34: three more events per period, each an update of Renode's schedule, and
    // the 16-bit timers of idle joints make a period every 328 us), this 1.2 s run takes
    // 11-12 s of wall time here (4.5 s with the DMA untimed): generous, so that only a real
    // stall fails.
    let options = RunOptions {
        stall_timeout: Duration::from_secs(60),
        completion_timeout: Some(Duration::from_secs(300)),
        ..RunOptions::default()
    };
    let report = arm
        .run_trajectory(&points, &options, |_| {})
        .unwrap_or_else(|e| panic!("{e}\n{}", board.log()));
    let status = report.final_status.unwrap();
    assert_eq!(status.state, State::Stopped);
    assert_eq!(usize::from(status.executed), points.len());
    assert!(!status.flags.has(StatusFlags::UNDERRUN), "{status:?}");
    let end = position(&board, &arm);
    assert_eq!(end[..JOINTS], points.last().unwrap().position[..JOINTS]);
    note(&format!(
        "run of {} points ({} ms) took {:.1} s of wall time",
        points.len(),
        points.len() * 10,
        began.elapsed().as_secs_f64()
    ));

    let asked = steps_asked(start, &points);
    let run = assert_run_is_the_oracles(&board, start, end, &points);
    for (j, asked) in asked.iter().enumerate() {
        assert_eq!(
            run.oracle[j].len(),
            *asked,
            "the oracle's pulses, joint {j}"
        );
    }
    note(&format!(
        "rising STEP edges per joint {:?}, the oracle's {:?}",
        run.counts(),
        run.oracle_counts()
    ));
    let (offset, setup, after_fall) = (run.offset, run.setup, run.after_fall);
    note(&format!(
        "{} DIR changes, each {}..={} ticks ({:.1}..={:.1} us) after the oracle's tick",
        run.dir_changes,
        run.least_late,
        run.most_late,
        ticks_us(run.least_late),
        ticks_us(run.most_late)
    ));
    let pins = run.pins;
    let starts: Vec<u64> = pins.iter().map(|p| p.start_ns).collect();
    let skew = starts.iter().max().unwrap() - starts.iter().min().unwrap();
    note(&format!(
        "every rise at the oracle's tick (lead-in {offset} ticks = {:.1} us); timers started \
         within {skew} ns of each other; DIR changes: least setup before the next rise {:?} \
         ticks ({:.1} us), least time after the last fall {:?} ticks ({:.1} us)",
        ticks_us(offset),
        setup,
        ticks_us(setup.unwrap_or(0)),
        after_fall,
        ticks_us(after_fall.unwrap_or(0))
    ));
    board.assert_healthy();
}

/// Abrupt reversals: joint 0 goes 10 steps forward, 10 back, ... in 400 points of 1 ms (10
/// kHz, a reversal every millisecond), so the step clock's DIR alarms fall everywhere in
/// TIM13's wrap. Every DIR change must come within the profile's latency budget
/// (`dir_latency_ns`, which the producer adds to the drivers' DIR setup before the next
/// pulse) and before the next rise, and the pulses signed by DIR must sum to the move.
///
/// It failed while the step clock (`step_timer.rs`, `program_compare`) armed TIM13's compare
/// only for an alarm less than half a wrap away and otherwise looked again at the next wrap,
/// by which time an alarm between half and one wrap away had passed: DIR up to half a wrap
/// (32,768 ticks, 164 us at 200 MHz) late against a 35 us budget, 151-154 of 399 reversals
/// over it, net +2 or +4 pulses for a move of 0. The compare is now armed for any alarm less
/// than a whole wrap away (board-logic's `step_clock::compare_for`, with its host test).
///
/// Run at [`CHIP_MIPS`]: the budget is the chip's (a masked span's instructions at 400 MHz);
/// at Renode's default 100 MIPS every masked span lasts four times as long in virtual time:
/// 12 of 399 DIR changes came 12,042-12,057 ticks late, one every 32 points, where a buffer
/// half (64 periods, 10 a point) ends on a reversal and its refill's critical section holds
/// TIM13 off (not the LOCATION reports: the same without them). At 400 MIPS the worst was
/// 2,639 ticks. The firmware before the fix fails at either speed (400 MIPS: 151 over,
/// net +2).
#[test]
fn abrupt_reversals_change_dir_within_the_budget() {
    require_renode!();
    let mut board = RenodeBoard::start_with_step_path(CHIP_MIPS);
    let arm = board.connect_from(HOSTS[0], emulated());
    arm.set_location(&[0; JOINTS]).unwrap();
    let start = [0; MAX_JOINTS];
    let mut at = start;
    let points: Vec<Point> = (0..400)
        .map(|k| {
            let mut to = at;
            to[0] += if k % 2 == 0 { 10 } else { -10 };
            let point = Point::from_motion(1_000, &at, &to);
            at = to;
            point
        })
        .collect();
    let report = arm
        .run_trajectory(&points, &RunOptions::default(), |_| {})
        .unwrap_or_else(|e| panic!("{e}\n{}", board.log()));
    assert_eq!(
        usize::from(report.final_status.unwrap().executed),
        points.len()
    );
    let pins = joints(&recorded(&board));
    let oracle = oracle(&segments(start, &points));
    let offset = lead_in(&pins, &oracle);
    assert_rises_match(&pins, &oracle, offset, true);
    // DIR lateness against the oracle's DIR ticks, each change.
    let budget = i64::from(NUCLEO_H743ZI2.dir_latency_ns) * i64::from(NUCLEO_H743ZI2.step_timer_hz)
        / 1_000_000_000;
    let expected: Vec<i64> = oracle.dirs[0]
        .iter()
        .filter(|(t, _)| *t > 0)
        .map(|&(t, _)| i64::try_from(t).unwrap() + offset)
        .collect();
    let late: Vec<i64> = pins[0]
        .dirs
        .iter()
        .zip(&expected)
        .map(|(&(got, _), &want)| got - want)
        .collect();
    let over = late.iter().filter(|&&l| l > budget).count();
    let worst = late.iter().copied().max().unwrap_or(0);
    let made = signed_pulses(&pins[0]);
    note(&format!(
        "{} reversals: DIR {}..={} ticks after the oracle's ({:.1} us at worst), {over} over the \
         {budget}-tick budget; net pulses on the pin {made}, the move 0",
        late.len(),
        late.iter().copied().min().unwrap_or(0),
        worst,
        ticks_us(worst)
    ));
    assert_eq!(pins[0].dirs.len(), expected.len(), "DIR changes");
    assert_eq!(
        over, 0,
        "DIR changes later than the budget (worst {worst} ticks)"
    );
    assert_eq!(made, 0, "pulses in the wrong direction");
    assert_pulse_and_dir_timing(&pins);
    board.assert_healthy();
}

/// The QEMU test's long run (`upload_streams_past_the_buffer_and_ends_exactly`): two joints,
/// 1.3 buffers (10,649 points of 1 ms) streamed while the run plays, every pulse checked
/// against the oracle.
#[test]
fn an_upload_past_the_buffer_makes_the_oracles_edges() {
    require_renode!();
    let mut board = RenodeBoard::start_with_step_path("");
    let arm = board.connect_from(HOSTS[0], emulated());
    arm.set_joints(2).unwrap();
    arm.set_location(&[0, 0]).unwrap();
    let capacity = usize::from(arm.status().unwrap().capacity);
    let start = [0; MAX_JOINTS];
    let points = sweep(start, 2, capacity * 13 / 10, 1, 1_000);
    let began = Instant::now();
    // Renode runs the board 3-6 times slower than wall time here, and armctl's upload
    // deadline is twice the trajectory's duration plus twice this (the buffer drains at the
    // board's pace): generous, so that only a real stall fails.
    let options = RunOptions {
        stall_timeout: Duration::from_secs(60),
        completion_timeout: Some(Duration::from_secs(400)),
        ..RunOptions::default()
    };
    let report = arm
        .run_trajectory(&points, &options, |_| {})
        .unwrap_or_else(|e| panic!("{e}\n{}", board.log()));
    let status = report.final_status.unwrap();
    assert_eq!(usize::from(status.executed), points.len());
    assert!(!status.flags.has(StatusFlags::UNDERRUN), "{status:?}");
    let end = position(&board, &arm);
    assert_eq!(end[..2], points.last().unwrap().position[..2]);
    note(&format!(
        "run of {} points of 1 ms streamed past the {capacity}-point buffer in {:.1} s of wall \
         time",
        points.len(),
        began.elapsed().as_secs_f64()
    ));
    let run = assert_run_is_the_oracles(&board, start, end, &points);
    note(&format!(
        "rising STEP edges per joint {:?}, the oracle's {:?}",
        run.counts(),
        run.oracle_counts()
    ));
    note(&format!(
        "every rise at the oracle's tick; DIR: least setup {:?} ticks, least after a fall \
         {:?} ticks; {} DIR changes {}..={} ticks after the oracle's",
        run.setup, run.after_fall, run.dir_changes, run.least_late, run.most_late
    ));
    board.assert_healthy();
}

/// The QEMU test's flood (`malformed_flood_during_a_run_changes_no_step`): 200 points of
/// 10 ms on six joints; once the run is under way a third host sends 2,000 malformed
/// datagrams; every edge is still the oracle's. (Started before the run, as on QEMU, the
/// flood kept the emulated board, 3-6 times slower than real time, from answering the
/// owner's NEW within armctl's 2 s: the board sheds the flooder's excess, but every frame
/// still costs the emulated MAC and CPU their time.)
#[test]
fn a_malformed_flood_during_a_run_changes_no_edge() {
    require_renode!();
    let mut board = RenodeBoard::start_with_step_path("");
    let arm = Arc::new(board.connect_from(HOSTS[0], emulated()));
    arm.set_location(&[0; JOINTS]).unwrap();
    let start = [0; MAX_JOINTS];
    let points = sweep(start, JOINTS, 200, 3, 10_000);
    // armctl's default wait for the run's end is wall time: twice the trajectory (2 s)
    // plus 10 s. The emulated board runs 3-6 times slower than real time, slower still
    // while it takes the flood's frames and on a loaded machine: past 14 s the wait
    // failed ("upload stalled at 200 of 200 points") with the run still playing
    // (STATUS: RUNNING, executed rising). Generous, so that only a real stall fails.
    let options = RunOptions {
        completion_timeout: Some(Duration::from_secs(120)),
        ..RunOptions::default()
    };
    let run = run_reporting_progress_with(&arm, points.clone(), options);
    run.wait_executed(5);
    let socket = board.udp_socket(HOSTS[2]);
    let sent = malformed_flood(&socket, 2_000);
    let report = run
        .join()
        .unwrap_or_else(|e| panic!("{e}\n{}", board.log()));
    let status = report.final_status.unwrap();
    assert!(sent > 500, "only {sent} malformed datagrams sent");
    assert_eq!(usize::from(status.executed), points.len());
    assert!(
        !status.flags.has(StatusFlags::STOPPED_BY_HOST) && !status.flags.has(StatusFlags::UNDERRUN),
        "{status:?}"
    );
    let end = position(&board, &arm);
    assert_eq!(end[..JOINTS], points.last().unwrap().position[..JOINTS]);
    let run = assert_run_is_the_oracles(&board, start, end, &points);
    note(&format!(
        "{sent} malformed datagrams during the run; rising edges {:?}, every one at the \
         oracle's tick",
        run.counts()
    ));
    board.assert_healthy();
}

/// The QEMU test's RETURN (`every_command_of_the_manual`): three joints from a set location
/// back to zero, planned by the firmware (no encoders answer: it trusts the step count). The
/// plan is the firmware's, so the pins are checked against the move: the pulses, their
/// direction, their width and DIR's timing.
///
/// Renode 1.15.3 cannot run it: its Cortex-M7 lacks the FPv5 instruction VMINNM.F64 (and
/// VMAXNM), which the planner's `f64::min` compiles to (`arm_core::plan`); the board takes a
/// UsageFault (CFSR 0x10000, UNDEFINSTR, at 0x0801bc62 in the build measured), which ends in
/// its DefaultHandler as `fault: UnexpectedInterrupt { irqn: -10 }`. The silicon has the
/// instruction. Runs with `--ignored` on a Renode that does.
#[test]
#[ignore = "Renode 1.15.3's Cortex-M7 has no VMINNM/VMAXNM (FPv5): RETURN's planner faults with UNDEFINSTR there"]
fn return_moves_the_pins_back_to_zero() {
    require_renode!();
    let mut board = RenodeBoard::start_with_step_path("");
    let arm = board.connect_from(HOSTS[0], emulated());
    arm.set_joints(3).unwrap();
    arm.set_location(&[400, -300, 200]).unwrap();
    arm.go_home().unwrap();
    let status = arm
        .wait_stopped(Duration::from_secs(120))
        .unwrap_or_else(|e| panic!("RETURN: {e}\n{}", board.log()));
    assert_eq!(status.state, State::Stopped);
    assert_eq!(position(&board, &arm)[..3], [0, 0, 0]);
    let pins = joints(&recorded(&board));
    let rises: Vec<usize> = pins.iter().map(|p| p.rises.len()).collect();
    let made: Vec<i32> = pins.iter().map(signed_pulses).collect();
    assert_eq!(rises, [400, 300, 200, 0, 0, 0, 0, 0]);
    assert_eq!(made, [-400, 300, -200, 0, 0, 0, 0, 0]);
    assert_pulse_and_dir_timing(&pins);
    assert_no_late_events(&board);
    note(&format!(
        "RETURN from [400, -300, 200]: rising edges {rises:?}, signed {made:?}"
    ));
    board.assert_healthy();
}

/// The QEMU test's e-stop (`emergency_stop_mid_run_freezes_the_joints`) on the DMA model as
/// RM0433 describes it ("DMA transfer suspension": a stream disabled by software sets its
/// TCIF). It failed before the stop (`step_dma/stop.rs`, `registers.rs`'s `disable_stream`)
/// cleared the TCIF its own disable set: read as "half 1 played and not refilled", it left
/// the positions a half buffer of periods ahead of the pins on the joints whose unplayed
/// period was in half 0 (measured: joint 0 reported 124 with 60 pulses made, joint 4 322
/// with 301). Then, once in nine runs, joints a step ahead of their pins: a period that
/// started after the outputs were all forced low and before the later joints' counters
/// stopped, counted with no edge; the stop now stops each counter before forcing its
/// output. To check on silicon: bring-up item 27.
#[test]
fn positions_after_an_estop_are_the_pulses_the_pins_made() {
    estop_positions_match_the_pins("");
}

/// The same e-stop with the DMA model's TCIF-on-disable turned off (a DMA that leaves TCIF
/// alone, as the firmware assumed before `disable_stream`): the stop must be right either
/// way, and this one exercises the rest of the stop path (stream positions from NDTR, the
/// unwind, no pulse after the stop) without the disable's TCIF.
#[test]
fn positions_after_an_estop_match_the_pins_if_a_disable_leaves_tcif_alone() {
    // Both controllers: joints 0-3 are on DMA1 since issue 34.
    estop_positions_match_the_pins(
        "sysbus.stepDma1 TransferCompleteOnDisable false; \
         sysbus.stepDma2 TransferCompleteOnDisable false",
    );
}

/// 300 points of 10 ms on six joints, STOPPED after 20 executed; `monitor` configures the
/// models.
fn estop_positions_match_the_pins(monitor: &str) {
    require_renode!();
    let mut board = RenodeBoard::start_with_step_path(monitor);
    let arm = Arc::new(board.connect_from(HOSTS[0], emulated()));
    let start = position(&board, &arm);
    let points = sweep(start, JOINTS, 300, 3, 10_000);
    let asked = steps_asked(start, &points);
    let total = points.len();
    let oracle = oracle(&segments(start, &points));
    match stop_mid_run(&arm, points, 20) {
        Err(Error::RunEnded {
            reason: RunEnd::Stopped,
            executed: Some(n),
            ..
        }) => assert!(usize::from(n) < total - 50, "executed {n}"),
        other => panic!("expected RunEnded(Stopped), got {other:?}\n{}", board.log()),
    }
    let status = arm.status().unwrap();
    assert_eq!(status.state, State::Stopped);
    assert!(status.flags.has(StatusFlags::STOPPED_BY_HOST));
    let reported = assert_stays_put(&arm, 30);
    assert_ne!(reported, start, "nothing moved before the stop");

    let pins = joints(&recorded(&board));
    let made: Vec<i32> = pins.iter().map(signed_pulses).collect();
    let moved: Vec<i32> = (0..MAX_JOINTS).map(|j| reported[j] - start[j]).collect();
    note(&format!(
        "after the e-stop: reported moves {moved:?}, signed pulses on the pins {made:?}; \
         joints with a pulse under way at the stop (left to end at its width) {:?}",
        (0..MAX_JOINTS)
            .filter(|&j| pins[j].under_way_at_stop.is_some())
            .collect::<Vec<_>>()
    ));
    assert_eq!(
        made, moved,
        "the positions reported are not the pulses made"
    );
    for j in 0..JOINTS {
        assert!(pins[j].rises.len() < asked[j], "joint {j} finished");
    }
    let offset = lead_in(&pins, &oracle);
    assert_rises_match(&pins, &oracle, offset, false);
    assert_pulse_and_dir_timing(&pins);
    // Nothing after: the record does not grow while the board keeps reporting.
    let before = board.edges().len();
    assert_stays_put(&arm, 10);
    let after = board.edges();
    assert_eq!(
        after.len(),
        before,
        "edges after the stop: {:?}",
        &after[before..]
    );
    board.assert_healthy();
}

/// The step path's models alone, without firmware (`tests/renode/step-models-check.resc`,
/// the CPU halted, registers written from the monitor): a timer pulsing at its ARR, a timer
/// reloaded through its DCR/DMAR burst by a circular DMA2 stream routed by DMAMUX1 (the
/// periods repeat in buffer order, the half-transfer and transfer-complete flags come and come
/// again, NDTR counts down by whole bursts), TIM8's CH1N stopping when MOE is cleared, and
/// DMA2 with a time per item (issue 34): two timers' bursts served lower stream first, the
/// later one landing after its timer's next update event, which replays the period before
/// (an extra pulse). Needs Renode only (no root, no network).
#[test]
fn the_models_alone_pulse_at_arr_and_reload_from_a_circular_stream() {
    let Some(run) = system_tests::renode::ScriptRun::run("step-models-check.resc", |dir| {
        format!("$edges=@{}; ", dir.join("edges.txt").display())
    }) else {
        return;
    };
    let out = &run.out;
    let text = std::fs::read_to_string(run.dir.join("edges.txt")).unwrap_or_default();
    assert!(out.contains("done"), "the script did not finish:\n{out}");
    let value = |label: &str| run.value_after(label);
    let edges: Vec<(u64, u8, bool)> = text
        .lines()
        .filter_map(|l| {
            let mut f = l.split_whitespace();
            Some((
                f.next()?.parse().ok()?,
                f.next()?.parse().ok()?,
                f.next()? == "1",
            ))
        })
        .collect();
    // (rise tick, width ticks) of the pulses on recorder line `line`.
    let pulses = |line: u8| -> Vec<(u64, u64)> {
        let mut rises = Vec::new();
        let mut open = None;
        for &(ns, l, high) in &edges {
            if l != line {
                continue;
            }
            match (high, open) {
                (true, None) => open = Some(ns),
                (false, Some(at)) => {
                    rises.push((at / NS_PER_TICK, (ns - at) / NS_PER_TICK));
                    open = None;
                }
                _ => {}
            }
        }
        rises
    };
    const END_TICKS: u64 = 40_000 / NS_PER_TICK;

    // 1. TIM2: ARR 99, CCR1 10.
    let tim2 = pulses(0);
    assert!(
        (100..=101).contains(&tim2.len()),
        "TIM2: {} pulses",
        tim2.len()
    );
    for (k, &(rise, width)) in tim2.iter().enumerate() {
        assert_eq!((rise, width), (100 * k as u64, 10), "TIM2 pulse {k}");
    }

    // 2. TIM3: the prelude (99/10 active, 149/15 preloaded), then the buffer's four periods
    //    (199/20, 299/30, 399/40, 499/no pulse) round and round.
    let mut expected = vec![(0, 10), (100, 15)];
    let cycle = [(200, 20), (300, 30), (400, 40), (500, 0)];
    let mut at = 250;
    'fill: loop {
        for (length, high) in cycle {
            if at >= END_TICKS {
                break 'fill;
            }
            if high > 0 {
                expected.push((at, high));
            }
            at += length;
        }
    }
    let tim3 = pulses(2);
    assert_eq!(tim3, expected, "TIM3's pulses from the circular stream");
    for when in ["20 us", "40 us"] {
        // Stream 2's HTIF (bit 20) and TCIF (bit 21), the second time after they were cleared.
        let lisr = value(&format!("LISR at {when}:"));
        let ndtr = value(&format!("NDTR at {when}:"));
        assert_eq!((lisr >> 20) & 3, 3, "DMA2 LISR at {when}: {lisr:#x}\n{out}");
        assert!(
            (1..=12).contains(&ndtr) && ndtr % 3 == 0,
            "NDTR at {when}: {ndtr}\n{out}"
        );
    }
    let updates = value("TIM3 update events:");
    let requests = value("TIM3 DMA requests:");
    let dmar = value("TIM3 DMAR writes:");
    let late = value("TIM3 late events:");
    assert_eq!(
        updates,
        requests + 1,
        "update events (the first is EGR.UG, no request)"
    );
    assert_eq!(
        dmar,
        3 * requests,
        "three DMAR writes per request (ARR, RCR, CCR1)"
    );
    assert_eq!(late, 0, "events handled after their time");
    // One request per overflow: every period start after the first, up to the end (an
    // overflow at the end's very instant may or may not be in).
    let mut starts = vec![100, 250];
    let mut at = 250;
    'periods: loop {
        for (length, _) in cycle {
            at += length;
            if at > END_TICKS {
                break 'periods;
            }
            starts.push(at);
        }
    }
    let overflows = starts.iter().filter(|&&t| t < END_TICKS).count() as u64;
    assert!(
        requests == overflows || requests == overflows + 1,
        "{requests} DMA requests for {overflows} overflows"
    );

    // 3. TIM8 CH1N: 5 ticks every 50 until MOE is cleared at 20 us, nothing after.
    let tim8 = pulses(5);
    assert!(tim8.len() >= 99, "TIM8 CH1N: {} pulses", tim8.len());
    for (k, &(rise, width)) in tim8.iter().enumerate() {
        if rise * NS_PER_TICK == 20_000 {
            continue; // the update event at the instant MOE is cleared: a zero-width glitch
        }
        assert_eq!((rise, width), (50 * k as u64, 5), "TIM8 CH1N pulse {k}");
        assert!(
            rise * NS_PER_TICK < 20_000,
            "TIM8 CH1N pulsed after MOE was cleared"
        );
    }
    note(&format!(
        "models alone: TIM2 {} pulses at ARR 99, TIM3 {} pulses from a 4-period circular stream \
         ({requests} DMA requests, {dmar} DMAR writes), TIM8 CH1N {} pulses until MOE off",
        tim2.len(),
        tim3.len(),
        tim8.len()
    ));

    // 4. DMA with time: TIM1 (stream 1, 100-tick periods) and TIM4 (stream 3, 50-tick
    //    periods) started together at 40 us on DMA2 at 40 ns an item. Stream 1 goes first:
    //    TIM1's pulses are its buffer's; TIM4's bursts land after its next update event,
    //    which replays the period before (a pulse its buffer does not have).
    const SECTION_4_NS: u64 = 40_000;
    const SECTION_4_TICKS: u64 = 4_000 / NS_PER_TICK;
    let since_40us = |line: u8| -> Vec<(u64, u64)> {
        pulses(line)
            .into_iter()
            .filter(|&(rise, _)| rise * NS_PER_TICK >= SECTION_4_NS)
            .map(|(rise, width)| (rise - SECTION_4_NS / NS_PER_TICK, width))
            .filter(|&(rise, _)| rise < SECTION_4_TICKS)
            .collect()
    };
    let tim1 = since_40us(4);
    let tim1_expected: Vec<(u64, u64)> = (0..SECTION_4_TICKS / 100)
        .map(|k| (100 * k, if k < 2 { 3 + k } else { 5 + (k - 2) % 4 }))
        .collect();
    assert_eq!(tim1, tim1_expected, "TIM1 (stream 1, served first)\n{out}");
    assert_eq!(value("TIM1 late bursts:"), 0, "TIM1's bursts\n{out}");
    let tim4 = since_40us(3);
    let tim4_buffer: Vec<(u64, u64)> = (0..SECTION_4_TICKS / 50)
        .map(|k| (50 * k, if k < 2 { 8 + k } else { 10 + (k - 2) % 4 }))
        .collect();
    let late = value("TIM4 late bursts:");
    assert!(late > 0, "TIM4's bursts should land late\n{out}");
    assert_eq!(tim4.len(), tim4_buffer.len(), "TIM4: a pulse every period");
    assert_ne!(
        tim4, tim4_buffer,
        "TIM4 played its buffer although its bursts were late"
    );
    let replayed = tim4.windows(2).filter(|w| w[0].1 == w[1].1).count();
    assert!(
        replayed > 0,
        "a late burst replays the period before: TIM4 {tim4:?}"
    );
    let waits = (
        value("stream 1 longest wait:"),
        value("stream 3 longest wait:"),
    );
    // Stream 1: at most one item under way ahead of its own (2 x 40 ns); stream 3: stream
    // 1's three words ahead of its first (4 x 40 ns).
    assert_eq!(
        waits,
        (80, 160),
        "longest waits (ns) of streams 1 and 3\n{out}"
    );
    note(&format!(
        "models alone, DMA with time: TIM1 (stream 1) {} pulses as its buffer, TIM4 (stream 3) \
         {late} late bursts, {replayed} periods replayed; longest waits {} ns and {} ns",
        tim1.len(),
        waits.0,
        waits.1
    ));
}

/// Issue 30 part 4 on the NUCLEO firmware, with steps: the owner, keyed, streams a long
/// trajectory in full windows (RUNING after four frames, the rest uploaded while it runs), a
/// stranger floods valid STATUS as fast as it can send, and a third host (an e-stop panel)
/// sends one STOPPED per run, never resent; 20 runs. Every single STOPPED takes effect: the
/// arm is STOPPED afterwards (STATUS from the panel) and its STEP lines go quiet. The frame's
/// landing at the board's MAC is the recorder's ([`STOPPED_LANDED`]), so a STOPPED lost
/// before the board (the host's TAP queue) is told from one the board missed, and an ACK lost
/// on the way back (counted, printed) from a STOPPED that did not take effect.
///
/// Prints, in Renode's virtual time, the time from each STOPPED landing to the last STEP edge
/// any joint made after it (p50, p90, max over the 20), and the receive counters; asserts the
/// emulated time only with a generous bound (10 ms: the chip's interrupt takes microseconds).
#[test]
fn every_single_stopped_halts_the_arm_under_a_flood_while_the_keyed_owner_streams() {
    use protocol::auth::{AuthKey, KEY_LEN};
    use protocol::{Command, MAX_DATAGRAM, Report, Tag};
    use std::sync::atomic::{AtomicBool, Ordering};
    require_renode!();
    const KEY: AuthKey = AuthKey([0x5a; KEY_LEN]);
    const STOPS: u8 = 20;
    // The flood: 1,300 datagrams per second of the board's *virtual* time
    // (`RENODE_FLOOD_RATE` changes it), sent every 20 ms of wall time as what is due by
    // then (at most 5 at once: `RENODE_FLOOD_BURST`). About the most the emulator carries
    // while the owner is still answered: each frame costs it a Python hook per Ethernet
    // register write (`nucleo-h743zi2.resc`), and its virtual time slows down with the
    // rate. Unpaced (~100k/s from one socket) the board's virtual time advanced 12 ms in
    // 10 s of wall time; at ~900/s (20 per 20 ms) and ~3,000/s the owner's STATUS got no
    // ACK within armctl's 2 s of wall time (the board's 50-100 ms). Paced in wall time
    // (5 per 20 ms, as before), a loaded machine slows Renode and not the flood: 5,570-8,247
    // per virtual second were printed on one, and the board's executor stalled 109-112 ms
    // (2 of 5 runs: the firmware's "check late" line). Paced in virtual time, a machine ten
    // times slower floods the board alike. Without the monitor's virtual time: wall pacing.
    let flood_burst: u64 = std::env::var("RENODE_FLOOD_BURST")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(5);
    let flood_rate: f64 = std::env::var("RENODE_FLOOD_RATE")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1_300.0);
    const FLOOD_PERIOD: Duration = Duration::from_millis(20);
    let mips = std::env::var("RENODE_FLOOD_MIPS").unwrap_or_else(|_| "100".into());
    let mut board =
        RenodeBoard::start_with_step_path(&format!("sysbus.cpu PerformanceInMips {mips}"));
    let panel = board.udp_socket(HOSTS[1]);
    panel.connect(BOARD).unwrap();
    panel
        .set_read_timeout(Some(Duration::from_millis(50)))
        .unwrap();
    let panel = common::Raw { socket: panel };
    // Counted while the arm has no key: a keyed arm answers plain STATUS AUTH_REQUIRED
    // (only STOPPED, DISCOVER and HELLO pass plain), and armctl does not read RX_COUNTERS.
    let before = common::rx_counters_after_stops(&panel, 0)
        .unwrap_or_else(|| panic!("RX_COUNTERS\n{}", board.log()));
    board
        .connect_from(HOSTS[0], emulated())
        .set_key(Some(KEY))
        .unwrap_or_else(|e| panic!("SET_KEY: {e}\n{}", board.log()));
    // Under the flood the board's virtual time runs 10-40 times slower than wall time:
    // a command is given up only after 30 s (copies still end 2 s after the first).
    let arm = Arc::new(board.connect_from(
        HOSTS[0],
        Options {
            key: Some(KEY),
            give_up_after: Duration::from_secs(30),
            ..emulated()
        },
    ));
    let flooder = board.udp_socket(HOSTS[2]);
    flooder.connect(BOARD).unwrap();
    let mut status_frame = [0u8; 8];
    let status_len = Command::Status.encode(1, &mut status_frame).unwrap();
    let done = AtomicBool::new(false);
    // Datagrams flooded so far, and when the first and the last STOPPED went out.
    let flooded = std::sync::atomic::AtomicU64::new(0);
    let mut flooded_at_stops = Vec::new();
    let options = RunOptions {
        start_after: Some(48),
        stall_timeout: Duration::from_secs(60),
        completion_timeout: Some(Duration::from_secs(300)),
        ..RunOptions::default()
    };
    struct Try {
        acked: bool,
        halted: bool,
    }
    let (flood, tries) = std::thread::scope(|scope| {
        let flood = scope.spawn(|| {
            let started = Instant::now();
            let virtual_start = board.virtual_time();
            let mut sent = 0u64;
            while !done.load(Ordering::Relaxed)
                && sent < 5_000_000
                && started.elapsed() < Duration::from_secs(600)
            {
                let due = match (virtual_start, board.virtual_time()) {
                    (Some(from), Some(now)) => {
                        (now.saturating_sub(from).as_secs_f64() * flood_rate) as u64
                    }
                    _ => sent + flood_burst,
                };
                let burst = due.saturating_sub(sent).min(flood_burst);
                for _ in 0..burst {
                    let _ = flooder.send(&status_frame[..status_len]);
                }
                sent += burst;
                flooded.store(sent, Ordering::Relaxed);
                std::thread::sleep(FLOOD_PERIOD);
            }
            (sent, started.elapsed())
        });
        // Whatever happens below (a panic too), the flood ends with the tries.
        struct EndsTheFlood<'a>(&'a AtomicBool);
        impl Drop for EndsTheFlood<'_> {
            fn drop(&mut self) {
                self.0.store(true, Ordering::Relaxed);
            }
        }
        let _ends_the_flood = EndsTheFlood(&done);
        let mut tries = Vec::new();
        for k in 0..STOPS {
            let here = (0..5)
                .find_map(|_| {
                    arm.current_location(Duration::from_secs(5))
                        .inspect_err(|e| note(&format!("try {k}: LOCATION: {e}")))
                        .ok()
                })
                .unwrap_or_else(|| panic!("try {k}: no LOCATION\n{}", board.log()))
                .position;
            // 12 s of motion, 100 keyed PENDINGs: uploaded while it runs.
            let points = sweep(here, JOINTS, 1200, 2, 10_000);
            let (progress, executed) = std::sync::mpsc::channel();
            let run = {
                let (arm, options) = (arm.clone(), options.clone());
                std::thread::spawn(move || {
                    arm.run_trajectory(&points, &options, |p| {
                        let _ = progress.send(p.executed);
                    })
                })
            };
            // Under way: 5 points executed (or the run ended: said, and the try fails).
            if !executed.iter().any(|n| n >= 5) {
                note(&format!("try {k}: the run ended first: {:?}", run.join()));
                tries.push(Try {
                    acked: false,
                    halted: false,
                });
                continue;
            }
            let mut stop = [0u8; 8];
            let len = Command::Stopped.encode(100 + k, &mut stop).unwrap();
            panel.socket.send(&stop[..len]).unwrap();
            flooded_at_stops.push(flooded.load(Ordering::Relaxed));
            let mut buf = [0u8; MAX_DATAGRAM];
            let sent_at = Instant::now();
            let mut acked = false;
            while !acked && sent_at.elapsed() < Duration::from_secs(3) {
                if let Ok(got) = panel.socket.recv(&mut buf)
                    && let Ok(frame) = Report::decode(&buf[..got])
                    && let Report::Ack(ack) = frame.body
                {
                    acked = frame.seq == 100 + k && ack.acked_tag == Tag::Stopped as u8;
                }
            }
            // The owner's view (the panel has no key): its STATUS is answered whatever the
            // flood (the owner's reserved share of the receive path).
            let halted = arm.status().is_ok_and(|s| s.state == State::Stopped);
            if !halted {
                // Missed: the owner stops the run (resent until ACKed) for the next try.
                let _ = arm.stop();
            }
            let _ = run.join();
            tries.push(Try { acked, halted });
        }
        drop(_ends_the_flood);
        (flood.join().unwrap(), tries)
    });
    arm.set_key(None)
        .unwrap_or_else(|e| panic!("clearing the key: {e}\n{}", board.log()));
    let after = common::rx_counters_after_stops(&panel, 0)
        .unwrap_or_else(|| panic!("RX_COUNTERS after\n{}", board.log()));
    let edges = recorded(&board);
    // From each STOPPED landing to the last STEP edge after it: the edges that follow it
    // without a 20 ms gap (a running joint steps every few ms; the next run starts later).
    let quiet_ns = 20_000_000;
    let landings: Vec<u64> = edges
        .iter()
        .filter(|e| e.line == STOPPED_LANDED)
        .map(|e| e.ns)
        .collect();
    let mut to_last_edge: Vec<f64> = landings
        .iter()
        .map(|&landed| {
            let mut last = landed;
            for e in edges.iter().filter(|e| e.line < 8 && e.ns > landed) {
                if e.ns - last > quiet_ns {
                    break;
                }
                last = e.ns;
            }
            (last - landed) as f64 / 1e3
        })
        .collect();
    to_last_edge.sort_by(f64::total_cmp);
    let q = |p: f64| {
        to_last_edge
            .get(((to_last_edge.len() as f64 - 1.0) * p).round() as usize)
            .copied()
            .unwrap_or(f64::NAN)
    };
    let halted = tries.iter().filter(|t| t.halted).count();
    let acked = tries.iter().filter(|t| t.acked).count();
    // The flood's rate in virtual time: datagrams sent between the first and the last
    // STOPPED over the virtual time between their landings.
    let virtual_rate = match (
        landings.first(),
        landings.last(),
        flooded_at_stops.first(),
        flooded_at_stops.last(),
    ) {
        (Some(&a), Some(&b), Some(&x), Some(&y)) if b > a => {
            (y - x) as f64 / ((b - a) as f64 / 1e9)
        }
        _ => f64::NAN,
    };
    note(&format!(
        "e-stop under a flood: {} STATUS in {:.1} s ({:.0}/s wall, {virtual_rate:.0}/s of \
         virtual time) from {}; {STOPS} single \
         STOPPEDs from {}, each into a keyed owner's streamed run: landed at the MAC {}, \
         halted the arm {halted}, ACKed {acked}; STOPPED landing -> last STEP edge (virtual \
         time) p50 {:.1} us, p90 {:.1}, max {:.1}; the ETH interrupt halted for {}; ring \
         dropped {}, ring full {}, shed {}, inbox dropped {}; missed: {:?}",
        flood.0,
        flood.1.as_secs_f64(),
        flood.0 as f64 / flood.1.as_secs_f64(),
        HOSTS[2],
        HOSTS[1],
        landings.len(),
        q(0.5),
        q(0.9),
        q(1.0),
        after.interrupt_stops - before.interrupt_stops,
        after.ring_dropped - before.ring_dropped,
        after.ring_full - before.ring_full,
        after.shed - before.shed,
        after.inbox_dropped - before.inbox_dropped,
        tries
            .iter()
            .enumerate()
            .filter(|(_, t)| !t.halted)
            .map(|(k, _)| k)
            .collect::<Vec<_>>(),
    ));
    assert_eq!(
        halted,
        usize::from(STOPS),
        "every single STOPPED halted the arm\n{}",
        board.log()
    );
    assert!(
        q(1.0) < 10_000.0,
        "the last STEP edge within 10 ms of virtual time after a STOPPED landed"
    );
    board.assert_healthy();
}

/// A rate change the board took (issue 32), on the oracle's clock (the board's run clock,
/// its joint timers' tick 0, less the lead-in).
#[derive(Clone, Copy, Debug)]
struct RateChange {
    at: u64,
    target: u64,
}

/// The warp of `changes` (in time order), each ramped with `ramp`.
fn warp_of(changes: &[RateChange], ramp: u64) -> Warp {
    let mut warp = Warp::IDENTITY;
    for c in changes {
        warp.change_rate(c.at, c.target, ramp)
            .unwrap_or_else(|e| panic!("{c:?}: {e:?}"));
    }
    warp
}

/// The ramp of a HOLD, RESUME or OVERRIDE on a board without ACCEL_SET limits (erased
/// settings): arm-core's `UNLIMITED_RAMP` at the board's step clock.
fn unlimited_ramp() -> u64 {
    let (accel, speed) = arm_core::controller::UNLIMITED_RAMP;
    arm_step::ramp_for(accel, speed, NUCLEO_H743ZI2.step_timing().tick_hz)
}

/// Where the oracle's rises first differ from the board's (moved onto the oracle's clock
/// by `offset`), both taken below tick `limit`: the earliest difference over the joints, as
/// the oracle's rise against the board's (`Less`: the oracle's comes earlier, or the board
/// has none), with the joint and the rise's index. `None`: equal.
fn first_difference(
    board: &[Joint; MAX_JOINTS],
    offset: i64,
    oracle: &Oracle,
    limit: u64,
) -> Option<(std::cmp::Ordering, usize, usize, u64)> {
    let mut first: Option<(std::cmp::Ordering, usize, usize, u64)> = None;
    for j in 0..MAX_JOINTS {
        let b: Vec<u64> = board[j]
            .rises
            .iter()
            .map(|&r| u64::try_from(i64::try_from(r).unwrap() - offset).unwrap())
            .filter(|&r| r < limit)
            .collect();
        let o: Vec<u64> = oracle[j].iter().copied().filter(|&r| r < limit).collect();
        let Some(k) = (0..b.len().max(o.len())).find(|&k| b.get(k) != o.get(k)) else {
            continue;
        };
        let (order, tick) = match (o.get(k), b.get(k)) {
            (Some(o), Some(b)) => (o.cmp(b), *o.min(b)),
            (Some(o), None) => (std::cmp::Ordering::Less, *o),
            (None, Some(b)) => (std::cmp::Ordering::Greater, *b),
            (None, None) => unreachable!(),
        };
        if first.is_none_or(|f| tick < f.3) {
            first = Some((order, j, k, tick));
        }
    }
    first
}

/// The tick (oracle's clock, in `lo..=hi`) at which the board took a rate change to
/// `target` (a slowing one if `slowing`), after the changes `before` and before `after`
/// (fixed): the one at which the oracle's rises below `limit` are the board's, found by
/// bisection. Each rise's tick is monotone in the change's tick (a slowing change taken
/// later lets every later rise come earlier or as early; a speeding one, later), so the
/// first difference says which way to go. One free number per change: that it makes
/// every edge of every joint the board's is the comparison. Panics, with the nearest
/// difference, if no tick does.
#[allow(clippy::too_many_arguments)]
fn fit_change(
    board: &[Joint; MAX_JOINTS],
    offset: i64,
    segments: &[Segment],
    (before, after): (&[RateChange], &[RateChange]),
    target: u64,
    slowing: bool,
    (mut lo, mut hi): (u64, u64),
    limit: u64,
) -> u64 {
    let mut nearest = None;
    while lo <= hi {
        let at = lo + (hi - lo) / 2;
        let mut changes = before.to_vec();
        changes.push(RateChange { at, target });
        changes.extend_from_slice(after);
        let oracle = oracle_warped(
            &NUCLEO_H743ZI2,
            segments,
            warp_of(&changes, unlimited_ramp()),
        );
        let Some(difference) = first_difference(board, offset, &oracle, limit) else {
            return at;
        };
        nearest = Some((at, difference));
        let later = (difference.0 == std::cmp::Ordering::Less) != slowing;
        if later {
            lo = at + 1;
        } else if at == 0 {
            break;
        } else {
            hi = at - 1;
        }
    }
    panic!(
        "no change tick to {target} makes the oracle's rises the board's: nearest (tick, \
         (oracle vs board, joint, rise, at)) {nearest:?}"
    );
}

/// The longest stretch without a rise on any joint, on the board's ticks: (last rise
/// before it, first after).
fn longest_pause(board: &[Joint; MAX_JOINTS]) -> (u64, u64) {
    let mut rises: Vec<u64> = board.iter().flat_map(|j| j.rises.iter().copied()).collect();
    rises.sort_unstable();
    rises
        .windows(2)
        .map(|w| (w[0], w[1]))
        .max_by_key(|(a, b)| b - a)
        .expect("rises")
}

/// Waits (bounded) until the MOTION report shows `flags` set (`set`) or clear.
fn wait_motion(arm: &armctl::Client, flags: u8, set: bool, what: &str) {
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let (status, motion) = arm.motion().unwrap();
        let motion = motion.expect("a MOTION report (issue 32's firmware)");
        if motion.flags.has(flags) == set {
            note(&format!("{what}: {motion:?}, executed {}", status.executed));
            return;
        }
        assert!(
            Instant::now() < deadline,
            "{what}: not within 120 s: {motion:?}"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// The run's options on the emulator: the hold lasts as long as the test takes to see it
/// at rest (several seconds of wall time), generous so that only a real stall fails.
fn held_run_options() -> RunOptions {
    RunOptions {
        stall_timeout: Duration::from_secs(60),
        completion_timeout: Some(Duration::from_secs(600)),
        ..RunOptions::default()
    }
}

/// The checks after a warped run: it ended with every point executed, every joint at its
/// last point, the pulses signed by DIR summing to the move, pulse width and DIR timing.
fn assert_warped_run_ends_exact(
    board: &RenodeBoard,
    arm: &armctl::Client,
    report: armctl::Result<armctl::RunReport>,
    start: [i32; MAX_JOINTS],
    points: &[Point],
) -> [Joint; MAX_JOINTS] {
    let report = report.unwrap_or_else(|e| panic!("{e}\n{}", board.log()));
    let status = report.final_status.unwrap();
    assert_eq!(status.state, State::Stopped);
    assert_eq!(usize::from(status.executed), points.len());
    assert!(!status.flags.has(StatusFlags::UNDERRUN), "{status:?}");
    let end = position(board, arm);
    assert_eq!(end[..JOINTS], points.last().unwrap().position[..JOINTS]);
    let pins = joints(&recorded(board));
    for j in 0..MAX_JOINTS {
        assert_eq!(
            signed_pulses(&pins[j]),
            end[j] - start[j],
            "joint {j}: net pulses"
        );
    }
    assert_pulse_and_dir_timing(&pins);
    assert_no_late_events(board);
    pins
}

/// Issue 32's Done-when on the NUCLEO ELF: a run of six joints (the QEMU test's sweep,
/// 120 points of 10 ms), HOLD 20 points in, the test waits for the MOTION report's
/// AT_REST, RESUME, the run ends: every joint exactly at its last point, and every rising
/// STEP edge of every joint at the tick of arm-step's oracle when the oracle takes the
/// same warp (hold at the tick the board took it, ramp to 0, resume, ramp back; erased
/// settings: no ACCEL_SET limit, so both ramps are `UNLIMITED_RAMP`'s slope).
///
/// The board takes a change at the first tick after what its producer has written
/// (`max(now, warp_horizon())` on the run's clock), which the host cannot know. So the
/// hold's tick is fitted: by bisection, the one tick at which the oracle's rises before the
/// pause are the board's (with a resume far after), then the resume's with the hold
/// fixed, on every rise of the run. Two numbers against every edge of every joint: a board
/// whose pulses did not follow the warp (a refill that placed a ramp's pulse a tick off)
/// matches at no tick. At [`CHIP_MIPS`]: the warp budget is the chip's (see
/// [`an_override_mid_run_makes_the_warped_oracles_edges`]).
#[test]
fn a_hold_and_resume_make_the_warped_oracles_edges() {
    require_renode!();
    let mut board = RenodeBoard::start_with_step_path(CHIP_MIPS);
    let arm = Arc::new(board.connect_from(HOSTS[0], emulated()));
    arm.set_location(&[0; JOINTS]).unwrap();
    let start = position(&board, &arm);
    let points = sweep(start, JOINTS, 120, 4, 10_000);
    let began = Instant::now();
    let run = run_reporting_progress_with(&arm, points.clone(), held_run_options());
    run.wait_executed(20);
    let ack = arm
        .hold()
        .unwrap_or_else(|e| panic!("HOLD: {e}\n{}", board.log()));
    assert_eq!(ack.state, State::Running);
    // Where the pins were just after the HOLD's ACK: its latency, printed below.
    let at_hold = position(&board, &arm);
    wait_motion(&arm, MotionFlags::AT_REST, true, "held");
    let ack = arm
        .resume()
        .unwrap_or_else(|e| panic!("RESUME: {e}\n{}", board.log()));
    assert_eq!(ack.state, State::Running);
    let pins = assert_warped_run_ends_exact(&board, &arm, run.join(), start, &points);
    note(&format!(
        "held run of {} points took {:.1} s of wall time",
        points.len(),
        began.elapsed().as_secs_f64()
    ));

    let segments = segments(start, &points);
    let offset = lead_in(&pins, &oracle(&segments));
    let shift = |tick: u64| u64::try_from(i64::try_from(tick).unwrap() - offset).unwrap();
    let (paused, moved) = longest_pause(&pins);
    let (paused, moved) = (shift(paused), shift(moved));
    let far = RateChange {
        at: moved,
        target: RATE_ONE,
    };
    let hold = fit_change(
        &pins,
        offset,
        &segments,
        (&[], &[far]),
        0,
        true,
        (0, paused),
        paused + (moved - paused) / 2,
    );
    let held = [RateChange {
        at: hold,
        target: 0,
    }];
    let resume = fit_change(
        &pins,
        offset,
        &segments,
        (&held, &[]),
        RATE_ONE,
        false,
        (hold + 1, moved),
        u64::MAX,
    );
    // The pins' time just after the HOLD's ACK: the unwarped oracle's tick of the last
    // pulse the fastest joint had made (before the hold's ramp, the two agree).
    let unwarped = oracle(&segments);
    let fastest = JOINTS - 1;
    let acked = usize::try_from(at_hold[fastest].abs_diff(start[fastest])).unwrap();
    let acked = unwarped[fastest][acked.saturating_sub(1)];
    note(&format!(
        "HOLD taken {:.1} ms after the pins' time at its ACK ({:.1} ms): the producer's \
         write-ahead (a change waits for the periods already written, up to two buffer \
         halves of each joint's)",
        ticks_us(i64::try_from(hold).unwrap() - i64::try_from(acked).unwrap()) / 1e3,
        ticks_us(i64::try_from(acked).unwrap()) / 1e3
    ));
    let changes = [
        held[0],
        RateChange {
            at: resume,
            target: RATE_ONE,
        },
    ];
    let oracle = oracle_warped(
        &NUCLEO_H743ZI2,
        &segments,
        warp_of(&changes, unlimited_ramp()),
    );
    assert_rises_match(&pins, &oracle, offset, true);
    let (least, most, dir_changes) = dir_lateness(&pins, &oracle, offset);
    note(&format!(
        "every rise at the warped oracle's tick: HOLD taken at tick {hold} ({:.1} ms into the \
         run), standstill from {:.1} ms to RESUME at {:.1} ms; rises per joint {:?}; {} DIR \
         changes {}..={} ticks after the oracle's",
        ticks_us(i64::try_from(hold).unwrap()) / 1e3,
        ticks_us(i64::try_from(paused).unwrap()) / 1e3,
        ticks_us(i64::try_from(resume).unwrap()) / 1e3,
        pins.iter().map(|p| p.rises.len()).collect::<Vec<_>>(),
        dir_changes,
        least,
        most
    ));
    board.assert_healthy();
}

/// OVERRIDE 50 mid-run on the NUCLEO ELF (issue 32): the rest of the run at half speed,
/// ramped; it ends exact, and every rising STEP edge is at the warped oracle's tick (the
/// change's tick fitted as in [`a_hold_and_resume_make_the_warped_oracles_edges`]).
///
/// Run at [`CHIP_MIPS`], as the hold: a warped pulse costs the step interrupts some 2,100
/// instructions (renode_cost), and at Renode's default 100 MIPS this run's six joints
/// (8,400 steps/s) ran a step stream dry during the ramp ("step stream underrun", the run
/// ended after 35 of 120 points); the NUCLEO's warp budget is the chip's 400 MHz.
#[test]
fn an_override_mid_run_makes_the_warped_oracles_edges() {
    require_renode!();
    let mut board = RenodeBoard::start_with_step_path(CHIP_MIPS);
    let arm = Arc::new(board.connect_from(HOSTS[0], emulated()));
    arm.set_location(&[0; JOINTS]).unwrap();
    let start = position(&board, &arm);
    let points = sweep(start, JOINTS, 120, 4, 10_000);
    let run = run_reporting_progress_with(&arm, points.clone(), held_run_options());
    run.wait_executed(20);
    arm.set_override(50)
        .unwrap_or_else(|e| panic!("OVERRIDE: {e}\n{}", board.log()));
    let pins = assert_warped_run_ends_exact(&board, &arm, run.join(), start, &points);

    let segments = segments(start, &points);
    let offset = lead_in(&pins, &oracle(&segments));
    let last = pins
        .iter()
        .filter_map(|p| p.rises.last())
        .max()
        .copied()
        .unwrap();
    let last = u64::try_from(i64::try_from(last).unwrap() - offset).unwrap();
    let half = RATE_ONE / 2;
    let at = fit_change(
        &pins,
        offset,
        &segments,
        (&[], &[]),
        half,
        true,
        (0, last),
        u64::MAX,
    );
    let oracle = oracle_warped(
        &NUCLEO_H743ZI2,
        &segments,
        warp_of(&[RateChange { at, target: half }], unlimited_ramp()),
    );
    assert_rises_match(&pins, &oracle, offset, true);
    let unwarped_end = oracle_of(&NUCLEO_H743ZI2, &segments)
        .rises
        .iter()
        .filter_map(|r| r.last())
        .max()
        .copied()
        .unwrap();
    note(&format!(
        "every rise at the warped oracle's tick: OVERRIDE 50 taken at {:.1} ms; last rise at \
         {:.1} ms (unwarped {:.1} ms)",
        ticks_us(i64::try_from(at).unwrap()) / 1e3,
        ticks_us(i64::try_from(last).unwrap()) / 1e3,
        ticks_us(i64::try_from(unwarped_end).unwrap()) / 1e3,
    ));
    board.assert_healthy();
}
