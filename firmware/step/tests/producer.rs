//! The pulse-time producer against the step engine (the oracle): for random trajectories
//! (direction changes, idle joints, pulses too close together to be on time, segments of
//! any length), random driver timing and tick rates (200 MHz, 10 MHz, odd ones), random
//! timer ranges (32-bit, 16-bit, tiny ones that force gap splitting) and random buffer
//! halves, every joint's rising edges, falling edges and DIR changes must be identical,
//! as must the late-pulse count and the positions. Half the cases run under a warp set
//! before the run (holds, resumes, overrides), and half of all cases get up to six more
//! rate changes asked for MID-RUN at random instants: the producer takes each at the
//! first tick its horizon allows (`warp_horizon`: nothing it wrote moves), and the engine
//! takes the same change at the same tick when its clock reaches the instant asked for.
//!
//! `producer_matches_engine_on_10m_pulses` runs seeded cases until at least
//! `STEP_EQ_PULSES` pulses (default 10,000,000) were compared; arm-step is built with
//! opt-level 3 in the dev profile (workspace Cargo.toml) so that this takes seconds under
//! plain `cargo test`. `STEP_EQ_SEED` picks another seed; a failure prints the case's seed.

mod common;

use arm_step::{
    MAX_JOINTS, MAX_RATE, PulsePeriod, PulseProducer, RATE_ONE, Segment, StepEngine, StepTiming,
    Warp, WarpError, ramp_for, sign_of,
};
use common::Recorder;
use proptest::prelude::*;

/// Segments held by both: every segment of a run is queued before it starts, so that the
/// engine's wait-for-push timing (which depends on when its owner pushes) stays out.
const QUEUE: usize = 64;

/// One joint's line changes: (tick, what).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Line {
    Rise(u64),
    Fall(u64),
    Dir(u64, bool),
}

/// A random case.
#[derive(Clone, Debug)]
struct Case {
    timing: StepTiming,
    max_period: [u32; MAX_JOINTS],
    /// Runs one after the other: (segments, start tick, ticks from stream start to it).
    runs: Vec<(Vec<Segment>, u64, u64)>,
    /// Fill sizes, cycled.
    halves: Vec<usize>,
    /// The time warp both take (holds, resumes, override changes), or the identity.
    warp: Warp,
    /// Rate changes asked for during the first run (`at` is the instant asked for).
    live: Vec<Change>,
}

/// A rate change during a run: asked for at controller tick `at` (in a case), taken at
/// `at` (once applied: the first tick the producer's horizon allows).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Change {
    asked: u64,
    at: u64,
    target: u64,
    ramp: u64,
}

/// xorshift64*.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n.max(1)
    }
    fn range(&mut self, lo: u64, hi: u64) -> u64 {
        lo + self.below(hi - lo + 1)
    }
}

fn random_case(rng: &mut Rng) -> Case {
    let tick_hz = match rng.below(7) {
        0 => 200_000_000,
        1 => 10_000_000,
        2 => 2_999_999,
        3 => 1_000_000,
        4 => 48_000_000,
        5 => 7_372_800,
        _ => rng.range(1_000_000, 250_000_000) as u32,
    };
    let per_us = (tick_hz / 1_000_000).max(1);
    let timing = StepTiming {
        tick_hz,
        pulse_width_ticks: rng.range(0, u64::from(3 * per_us)) as u32,
        dir_setup_ticks: rng.range(0, u64::from(6 * per_us)) as u32,
        step_low_ticks: rng.range(0, u64::from(3 * per_us)) as u32,
    };
    let max_period = core::array::from_fn(|_| match rng.below(4) {
        0 => u32::MAX,
        1 => 1 << 16,
        2 => rng.range(2, 2_000) as u32,
        _ => rng.range(500, 100_000) as u32,
    });
    let runs: Vec<_> = (0..rng.range(1, 2))
        .map(|_| {
            let count = rng.range(1, QUEUE as u64) as usize;
            // A rate scale per run: mostly reachable, sometimes far over the pins' limit.
            // Many steps per segment (at odd tick rates the modulus then exceeds u32: the
            // u64 path) in some runs.
            let most_steps = if rng.below(16) == 0 { 20_000 } else { 600 };
            let rate_cap = match rng.below(4) {
                0 => 2_000_000u64,
                1 => 1_000,
                _ => u64::from(timing.max_step_rate_hz()),
            };
            let segments = (0..count)
                .map(|_| {
                    let duration_us = match rng.below(200) {
                        // Longer than 2^31 ticks at the fast tick rates: the u64 path.
                        0 => rng.range(5_000_000, 20_000_000),
                        1..=25 => rng.range(1, 20),
                        26..=50 => rng.range(20_000, 3_000_000),
                        _ => rng.range(20, 3_000),
                    } as u32;
                    let max = (rate_cap * u64::from(duration_us) / 1_000_000).clamp(1, most_steps);
                    let steps = core::array::from_fn(|_| match rng.below(5) {
                        0 => 0,
                        1 => max as i32,
                        2 => -(max as i32),
                        _ => rng.range(0, 2 * max) as i32 - max as i32,
                    });
                    Segment { duration_us, steps }
                })
                .collect::<Vec<_>>();
            let lead = rng.range(0, 3 * u64::from(timing.dir_setup_ticks) + 2);
            (segments, rng.range(lead, 1 << 40), lead)
        })
        .collect();
    let halves = (0..rng.range(1, 4))
        .map(|_| rng.range(1, 80) as usize)
        .collect();
    // Drawn last, so that the rest of a seed's case is what it was before warps.
    let warp = random_warp(rng, tick_hz, &runs);
    let live = random_changes(rng, tick_hz, &runs);
    Case {
        timing,
        max_period,
        runs,
        halves,
        warp,
        live,
    }
}

/// A rate from 0 (a hold) to 200 %, and a ramp slope that makes a full 0-100 % swing in 1 us
/// to `span_us`.
fn random_rate_and_ramp(rng: &mut Rng, tick_hz: u32, span_us: u64) -> (u64, u64) {
    let target = match rng.below(4) {
        0 => 0,
        1 => rng.range(RATE_ONE / 10, RATE_ONE),
        2 => rng.range(RATE_ONE, MAX_RATE),
        _ => RATE_ONE,
    };
    // A full swing in `swing_us`: accel / speed = 1 / swing (module header of warp).
    let swing_us = rng.range(1, span_us.max(1));
    let accel = (1_000_000_000 / swing_us) as u32;
    (target, ramp_for(accel.max(1), 1_000, tick_hz))
}

/// Half the cases: one to six rate changes asked for during the first run, at random
/// instants over about twice its unwarped length; the last one leaves the rate above 0
/// (the run ends).
fn random_changes(rng: &mut Rng, tick_hz: u32, runs: &[(Vec<Segment>, u64, u64)]) -> Vec<Change> {
    if rng.below(2) == 0 {
        return Vec::new();
    }
    let (segments, first, _) = &runs[0];
    let span_us: u64 = segments.iter().map(|s| u64::from(s.duration_us)).sum();
    let span = span_us * u64::from(tick_hz) / 1_000_000;
    let count = rng.range(1, 6);
    let mut asked = *first;
    (0..count)
        .map(|i| {
            asked += rng.below(2 * span / count + 1);
            let (mut target, ramp) = random_rate_and_ramp(rng, tick_hz, span_us);
            if i + 1 == count && target == 0 {
                target = RATE_ONE;
            }
            Change {
                asked,
                at: asked,
                target,
                ramp,
            }
        })
        .collect()
}

/// Half the cases: one to six rate changes (holds, resumes, overrides of 10-200 %) from the
/// first run's start over about its length, with ramps of 1 us to the run's length for a
/// full 0-100 % swing; the last change leaves the rate above 0 (the runs end).
fn random_warp(rng: &mut Rng, tick_hz: u32, runs: &[(Vec<Segment>, u64, u64)]) -> Warp {
    let mut warp = Warp::IDENTITY;
    if rng.below(2) == 0 {
        return warp;
    }
    let (segments, first, _) = &runs[0];
    let span_us: u64 = segments.iter().map(|s| u64::from(s.duration_us)).sum();
    let span = span_us * u64::from(tick_hz) / 1_000_000;
    let changes = rng.range(1, 6);
    let mut at = *first;
    for i in 0..changes {
        at += rng.below(2 * span / changes + 1);
        let (mut target, ramp) = random_rate_and_ramp(rng, tick_hz, span_us);
        if i + 1 == changes && target == 0 {
            target = RATE_ONE;
        }
        warp.change_rate(at, target, ramp)
            .expect("at most 6 changes, rates in range");
    }
    warp
}

/// Each joint's changes in time order; at one tick a fall, then a DIR change (made when
/// the previous pulse falls), then a rise (a DIR setup of 0).
fn sort_lines(lines: &mut [Vec<Line>]) {
    for joint_lines in lines {
        joint_lines.sort_by_key(|line| match *line {
            Line::Fall(t) => (t, 0),
            Line::Dir(t, _) => (t, 1),
            Line::Rise(t) => (t, 2),
        });
    }
}

/// What a run of either gives: per joint line changes, late pulses, positions.
type Lines = (Vec<Vec<Line>>, u32, [i32; MAX_JOINTS]);

/// Where each run started (its origin on trajectory time, its stream's start on controller
/// time; each starts after the previous one ran dry) and where each ended.
type Runs = (Vec<(u64, u64)>, Vec<u64>);

/// The engine's line changes per joint, its late pulses and positions, and its runs.
/// `changes` (the producer's, as it applied them) are taken when the engine's clock reaches
/// the instant each was asked for, at the tick the producer took it.
fn engine_lines(case: &Case, changes: &[Change]) -> (Lines, Runs) {
    let mut starts = Vec::new();
    let mut ends = Vec::new();
    let mut engine = StepEngine::<QUEUE>::new(case.timing);
    assert!(engine.set_warp(case.warp));
    let mut pins = Recorder::default();
    let mut lines = vec![Vec::new(); MAX_JOINTS];
    let mut last_end = 0;
    for (run, (segments, start, lead)) in case.runs.iter().enumerate() {
        let start = *start.max(&(last_end + lead));
        // The run's segments start on trajectory time: at the first trajectory tick the
        // warp reaches at or after controller tick `start`.
        let origin = match start {
            0 => 0,
            _ => engine.warp().trajectory_tick(start - 1) + 1,
        };
        starts.push((origin, start - lead));
        for segment in segments {
            assert!(engine.push(*segment).is_ok());
        }
        engine.start(origin);
        let mut pending = if run == 0 { changes } else { &[] };
        let mut now = start - lead;
        loop {
            while let Some((change, rest)) = pending.split_first() {
                if change.asked > now {
                    break;
                }
                assert!(
                    engine.warp_horizon() <= change.at,
                    "the engine commits no further than the producer"
                );
                engine
                    .change_warp(change.at, change.target, change.ramp)
                    .expect("at or after the horizon, room in the warp");
                pending = rest;
            }
            pins.now = now;
            let poll = engine.poll(now, &mut pins);
            match poll.next_deadline {
                // The next deadline, or the next instant a change is asked for.
                Some(deadline) => {
                    now = pending
                        .first()
                        .map_or(deadline, |change| deadline.min(change.asked))
                }
                None => break,
            }
        }
        // Changes the producer took after the run's end (asked for while it still wrote
        // its last periods): taken here too, so that the next run starts on the same map.
        for change in pending {
            assert!(change.asked > now, "asked for during the run");
            engine
                .change_warp(change.at, change.target, change.ramp)
                .expect("between runs");
        }
        ends.push(now);
        last_end = now + 1;
    }
    for event in &pins.events {
        let line = match event.edge {
            common::Edge::Rise => Line::Rise(event.tick),
            common::Edge::Fall => Line::Fall(event.tick),
            common::Edge::Dir(level) => Line::Dir(event.tick, level),
            common::Edge::Cut => unreachable!("no stop in these runs"),
        };
        lines[event.joint].push(line);
    }
    sort_lines(&mut lines);
    (
        (lines, engine.late_pulses(), engine.positions()),
        (starts, ends),
    )
}

/// Takes the changes asked for by now: once every joint still filling has written past the
/// instant asked for, at the producer's horizon or that instant, whichever is later. One
/// asked for after the run's end changes nothing in it (the maps agree up to the change)
/// and is taken all the same, so that the next run starts on the map the engine has.
fn take_changes(
    producer: &mut PulseProducer<QUEUE>,
    pending: &mut &[Change],
    written: &[u64; MAX_JOINTS],
    done: &[bool; MAX_JOINTS],
    applied: &mut Vec<Change>,
) {
    while let Some((change, rest)) = pending.split_first() {
        let reached = (0..MAX_JOINTS).all(|j| done[j] || written[j] >= change.asked);
        if !reached {
            return;
        }
        let horizon = producer.warp_horizon();
        if horizon > 0 {
            // Before the horizon: refused, nothing changed.
            assert_eq!(
                producer.change_warp(horizon - 1, change.target, change.ramp),
                Err(WarpError::Committed)
            );
        }
        let at = change.asked.max(horizon);
        producer
            .change_warp(at, change.target, change.ramp)
            .expect("at the horizon, room in the warp");
        applied.push(Change { at, ..*change });
        *pending = rest;
    }
}

/// The producer's line changes per joint (periods played back from each stream's start),
/// its late pulses and positions, the changes it applied and its runs; also checks that the
/// buffers say what the positions say.
fn producer_lines(case: &Case) -> (Lines, Vec<Change>, Runs) {
    let mut producer = PulseProducer::<QUEUE>::new(case.timing, case.max_period);
    assert!(producer.set_warp(case.warp));
    let mut lines: Vec<Vec<Line>> = vec![Vec::new(); MAX_JOINTS];
    let mut periods = [PulsePeriod::ZERO; 80];
    let mut deltas;
    let mut fills = 0usize;
    let mut moved = [0i32; MAX_JOINTS];
    let (mut starts, mut ends, mut applied) = (Vec::new(), Vec::new(), Vec::new());
    let mut last_end = 0;
    for (run, (segments, start, lead)) in case.runs.iter().enumerate() {
        let start = *start.max(&(last_end + lead));
        let origin = match start {
            0 => 0,
            _ => producer.warp().trajectory_tick(start - 1) + 1,
        };
        let stream = start - lead;
        starts.push((origin, stream));
        for segment in segments {
            assert!(producer.push(*segment).is_ok());
        }
        producer.start(origin, stream);
        let mut pending = if run == 0 { &case.live[..] } else { &[] };
        // Every joint is filled in turn, a half at a time, until it idles: its last pulse
        // is written.
        let mut at = [stream; MAX_JOINTS];
        let mut done = [false; MAX_JOINTS];
        let mut guard = 0;
        while !done.iter().all(|&d| d) {
            guard += 1;
            assert!(guard < 10_000_000, "producer never drained");
            take_changes(&mut producer, &mut pending, &at, &done, &mut applied);
            for joint in 0..MAX_JOINTS {
                if done[joint] {
                    continue;
                }
                let half = case.halves[fills % case.halves.len()];
                fills += 1;
                let mut dirs = Vec::new();
                deltas = [0; 80];
                let filled = producer.fill(
                    joint,
                    &mut periods[..half],
                    &mut deltas[..half],
                    &mut |tick, positive| dirs.push(Line::Dir(tick, positive)),
                );
                let mut pulses = 0;
                // Every fill marks its first pulse: the starting sign must not matter.
                let signed: Vec<i8> = sign_of(&periods[..half], &deltas[..half], 0).collect();
                for (period, &sign) in periods[..half].iter().zip(&signed) {
                    assert!(period.high == 0 || u64::from(period.high) < period.ticks());
                    assert!(period.ticks() <= u64::from(producer.max_period_ticks(joint)));
                    assert_eq!(period.high != 0, sign != 0, "pulse without a sign");
                    moved[joint] += i32::from(sign);
                    if period.high != 0 {
                        pulses += 1;
                        lines[joint].push(Line::Rise(at[joint]));
                        lines[joint].push(Line::Fall(at[joint] + u64::from(period.high)));
                    }
                    at[joint] += period.ticks();
                }
                lines[joint].extend(dirs);
                assert_eq!(filled.pulses, pulses);
                assert_eq!(filled.end_tick, at[joint]);
                // Idle: every pulse of the run written (nothing more is pushed).
                done[joint] = filled.idle;
            }
        }
        // Changes asked for after the last pulse was written may still move the run's end.
        take_changes(&mut producer, &mut pending, &at, &done, &mut applied);
        assert!(pending.is_empty());
        assert!(producer.drained());
        let end = producer
            .run_end_tick()
            .expect("every pulse written: the run's end is known");
        ends.push(end);
        last_end = end + 1;
        producer.end_run();
        assert!(!producer.is_running());
        assert_eq!(
            moved,
            producer.positions(),
            "signs marked beside the periods"
        );
    }
    sort_lines(&mut lines);
    (
        (lines, producer.late_pulses(), producer.positions()),
        applied,
        (starts, ends),
    )
}

/// Compares one case; returns the pulses compared, how many of them were late and the
/// changes taken mid-run.
fn compare(case: &Case) -> Result<(u64, u64, usize), String> {
    let ((produced, produced_late, produced_positions), applied, produced_runs) =
        producer_lines(case);
    let ((engine, late, positions), runs) = engine_lines(case, &applied);
    if runs != produced_runs {
        return Err(format!(
            "runs (starts, ends): engine {runs:?}, producer {produced_runs:?}"
        ));
    }
    for joint in 0..MAX_JOINTS {
        if engine[joint] != produced[joint] {
            let first = engine[joint]
                .iter()
                .zip(&produced[joint])
                .position(|(a, b)| a != b)
                .unwrap_or(engine[joint].len().min(produced[joint].len()));
            let from = first.saturating_sub(3);
            return Err(format!(
                "joint {joint}: first difference at change {first} of {} / {}:\n engine   {:?}\n producer {:?}",
                engine[joint].len(),
                produced[joint].len(),
                &engine[joint][from..(first + 4).min(engine[joint].len())],
                &produced[joint][from..(first + 4).min(produced[joint].len())],
            ));
        }
    }
    if late != produced_late {
        return Err(format!(
            "late pulses: engine {late}, producer {produced_late}"
        ));
    }
    if positions != produced_positions {
        return Err(format!(
            "positions: engine {positions:?}, producer {produced_positions:?}"
        ));
    }
    let pulses = engine
        .iter()
        .flatten()
        .filter(|l| matches!(l, Line::Rise(_)))
        .count() as u64;
    Ok((pulses, u64::from(late), applied.len()))
}

#[test]
fn producer_matches_engine_on_10m_pulses() {
    let target: u64 = std::env::var("STEP_EQ_PULSES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10_000_000);
    let seed: u64 = std::env::var("STEP_EQ_SEED")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(0x5eed_0fa1_1ed9_e5e5);
    let started = std::time::Instant::now();
    let mut pulses = 0u64;
    let mut late = 0u64;
    let mut cases = 0u64;
    let (mut warped_cases, mut warped_pulses) = (0u64, 0u64);
    let (mut live_cases, mut live_pulses, mut live_changes) = (0u64, 0u64, 0usize);
    while pulses < target {
        let case_seed = seed.wrapping_add(cases.wrapping_mul(0x9e37_79b9_7f4a_7c15)) | 1;
        let case = random_case(&mut Rng(case_seed));
        match compare(&case) {
            Ok((n, l, changes)) => {
                pulses += n;
                late += l;
                if changes > 0 {
                    live_cases += 1;
                    live_pulses += n;
                    live_changes += changes;
                }
                if !case.warp.is_identity() {
                    warped_cases += 1;
                    warped_pulses += n;
                }
            }
            Err(e) => panic!("case seed {case_seed:#x} ({case:?}):\n{e}"),
        }
        cases += 1;
    }
    println!(
        "producer == engine on {pulses} pulses ({late} of them late) in {cases} cases, \
         {warped_pulses} pulses in {warped_cases} cases under a warp set before the run, \
         {live_pulses} pulses in {live_cases} cases with {live_changes} rate changes taken \
         mid-run ({:.1} s)",
        started.elapsed().as_secs_f64()
    );
    assert!(warped_pulses > 0, "the warped cases moved");
    assert!(live_changes > 0, "changes were taken mid-run");
    assert!(pulses >= target);
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 64, ..ProptestConfig::default() })]

    /// The same comparison as a property, for shrinking a failure to a small case.
    #[test]
    fn producer_matches_engine(seed in any::<u64>()) {
        let case = random_case(&mut Rng(seed | 1));
        if let Err(e) = compare(&case) {
            return Err(TestCaseError::fail(e));
        }
    }
}
